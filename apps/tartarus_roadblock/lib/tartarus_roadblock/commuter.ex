defmodule TartarusRoadblock.Commuter do
  @moduledoc """
  The commuter Santa's controller: a static agent on the host Santa talks to. Each control
  step (a `:tick` request from the scenario's clock) it reads Santa's line sensors,
  ultrasonic sensor and odometry through its host's plugins, and follows the line with the
  proportional PFA A4 (`TartarusArena.PFA.A4`) until it reaches its destination.

  When the ultrasonic sensor sees something closer than `stop_cm` (20) it stops, and the
  first time it tells the monitoring node's agent (`{:blocked, report}`, a
  `Tartarus.cast/3` to `monitor`), with an estimate of where the obstacle is. It starts
  again once the way is clear beyond `clear_cm` (40).

  Args: `%{monitor: agent_ref, dest_x: x}`. The tick's reply: `%{phase: :driving |
  :stopped | :arrived, pose:, ultrasonic:, reported: boolean}`.
  """
  use Tartarus.Agent

  alias TartarusArena.PFA.A4

  @stop_cm 20
  @clear_cm 40

  @impl true
  @doc "Starts on the line, driving."
  def init(%{monitor: _, dest_x: _} = args) do
    {:stay,
     Map.merge(args, %{phase: :driving, pfa: A4.init(base: 0.8), reported: false, stops: 0})}
  end

  @impl true
  @doc "`:tick`: one control step (see the moduledoc)."
  def handle_message(:tick, from, s) do
    {:ok, {x, _, _} = pose} = Tartarus.Agent.read(:motors, :odometry)
    {:ok, us} = Tartarus.Agent.read(:sonar)
    {:ok, line} = Tartarus.Agent.read(:line)

    {s, just_reported} =
      cond do
        s.phase == :arrived or x >= s.dest_x ->
          :ok = Tartarus.Agent.write(:motors, :stop)
          {%{s | phase: :arrived}, false}

        us < @stop_cm or (s.phase == :stopped and us < @clear_cm) ->
          :ok = Tartarus.Agent.write(:motors, :stop)
          s = if s.phase == :driving, do: %{s | phase: :stopped, stops: s.stops + 1}, else: s

          if s.reported do
            {s, false}
          else
            report = %{robot: "santa", pose: pose, ultrasonic: us, block: estimate(pose, us)}
            Tartarus.cast(s.monitor, {:blocked, report})
            {%{s | reported: true}, true}
          end

        true ->
          {{l, r}, pfa} = A4.control(line, 0.05, s.pfa)
          :ok = Tartarus.Agent.write(:motors, {:wheels, l, r})
          {%{s | phase: :driving, pfa: pfa}, false}
      end

    Tartarus.Agent.reply(from, %{
      phase: s.phase,
      pose: pose,
      ultrasonic: us,
      reported: just_reported
    })

    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  # Where the obstacle is: the echo's distance ahead of Santa's front (radius 7 cm), plus
  # half a typical block (4 cm).
  defp estimate({x, y, th}, us) do
    d = 0.07 + us / 100 + 0.04
    {x + d * :math.cos(th), y + d * :math.sin(th)}
  end
end
