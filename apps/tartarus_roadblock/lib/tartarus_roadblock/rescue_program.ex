defmodule TartarusRoadblock.RescueProgram do
  @moduledoc """
  The rescue program the administrator's agent carries to a rescue robot (thesis §2.4):
  drive from the dock to the roadblock, take it in the claws, carry it off the path, put it
  down, and drive back to the dock. It is a pure controller, `(readings, state) ->
  {commands, state}`, calling nothing but Kernel and `:math`, so the agent ships it as code
  to whichever robot host it chooses and runs it there against that host's devices.

  Readings: `%{pose: {x, y, heading}, ultrasonic: cm, holding: puck_id | nil}` (odometry,
  the ultrasonic sensor, the claws). Commands: `{:wheels, left, right}` and
  `{:grip, :close | :open}`.

  Phases, in order: `:to_block` (drive to a point `approach` metres on the far side of the
  block from the path, across the path), `:face` (turn towards the block), `:approach`
  (creep forward until the block is in the claws' zone, then close them), `:carry`
  (reverse, holding it, until it is `lift` metres off the path), `:release` (open),
  `:back_off` (reverse a little more; a robot whose claws do not take the block after 5 tries gives
  up and backs off from there), `:home` (drive to the dock), `:dock` (turn to the
  dock's heading), `:done`.

      iex> s = TartarusRoadblock.RescueProgram.init(block: {1.4, 0.8}, dock: {2.0, 2.3, -1.5708})
      iex> s.phase
      :to_block
      iex> {[{:wheels, _l, _r}], s} =
      ...>   TartarusRoadblock.RescueProgram.control(%{pose: {2.0, 2.3, -1.5708}, ultrasonic: 200, holding: nil}, s)
      iex> s.phase
      :to_block
  """

  @typedoc "The program's state."
  @type t :: %{
          phase: atom(),
          block: {float(), float()},
          dock: {float(), float(), float()},
          side: 1 | -1,
          approach: float(),
          lift: float(),
          grips: non_neg_integer()
        }

  @typedoc "What the program reads each control step."
  @type readings :: %{
          pose: {number(), number(), number()},
          ultrasonic: number(),
          holding: term()
        }

  @typedoc "What the program commands."
  @type command :: {:wheels, float(), float()} | {:grip, :open | :close}

  @doc """
  The program for a block at `block: {x, y}` (on a path along x) and a robot docked at
  `dock: {x, y, heading}`. Options `approach` (0.32 m) and `lift` (0.42 m): how far from
  the path the robot starts its approach and puts the block down, on the dock's side.
  """
  @spec init(keyword()) :: t()
  def init(opts) do
    {bx, by} = Keyword.fetch!(opts, :block)
    {dx, dy, dth} = Keyword.fetch!(opts, :dock)

    %{
      phase: :to_block,
      block: {bx * 1.0, by * 1.0},
      dock: {dx * 1.0, dy * 1.0, dth * 1.0},
      side: if(dy >= by, do: 1, else: -1),
      approach: Keyword.get(opts, :approach, 0.32),
      lift: Keyword.get(opts, :lift, 0.42),
      grips: 0
    }
  end

  @doc "One control step: the commands for these readings, and the next state."
  @spec control(readings(), t()) :: {[command()], t()}
  def control(%{pose: {x, y, th}} = r, s) do
    {bx, by} = s.block
    side = s.side

    case s.phase do
      :to_block ->
        target = {bx, by + side * s.approach}

        case go_to({x, y, th}, target, 0.02) do
          :arrived -> {[stop()], %{s | phase: :face}}
          cmd -> {[cmd], s}
        end

      :face ->
        case turn_to(th, :math.atan2(by - y, bx - x)) do
          :aligned -> {[stop()], %{s | phase: :approach}}
          cmd -> {[cmd], s}
        end

      :approach ->
        near? = r.ultrasonic <= 1 or dist(x, y, bx, by) <= 0.112

        cond do
          r.holding != nil ->
            {[stop()], %{s | phase: :carry}}

          # The claws never closed on it (a robot without claws): give up, go home.
          s.grips >= 5 ->
            {[stop()], %{s | phase: :back_off, lift: side * (y - by) - 0.12}}

          near? ->
            {[stop(), {:grip, :close}], %{s | grips: s.grips + 1}}

          true ->
            e = wrap(:math.atan2(by - y, bx - x) - th)
            {[{:wheels, 0.3 - 0.5 * e, 0.3 + 0.5 * e}], s}
        end

      :carry ->
        if side * (y - by) >= s.lift,
          do: {[stop(), {:grip, :open}], %{s | phase: :release}},
          else: {[{:wheels, -0.5, -0.5}], s}

      :release ->
        {[{:wheels, -0.4, -0.4}], %{s | phase: :back_off}}

      :back_off ->
        if side * (y - by) >= s.lift + 0.12,
          do: {[stop()], %{s | phase: :home}},
          else: {[{:wheels, -0.4, -0.4}], s}

      :home ->
        {dx, dy, _} = s.dock

        case go_to({x, y, th}, {dx, dy}, 0.02) do
          :arrived -> {[stop()], %{s | phase: :dock}}
          cmd -> {[cmd], s}
        end

      :dock ->
        case turn_to(th, elem(s.dock, 2)) do
          :aligned -> {[stop()], %{s | phase: :done}}
          cmd -> {[cmd], s}
        end

      :done ->
        {[stop()], s}
    end
  end

  defp stop, do: {:wheels, 0.0, 0.0}

  # Turn in place towards the target, then drive to it steering by the heading error.
  defp go_to({x, y, th}, {tx, ty}, tol) do
    d = dist(x, y, tx, ty)

    if d <= tol do
      :arrived
    else
      e = wrap(:math.atan2(ty - y, tx - x) - th)

      if abs(e) > 0.3 do
        w = max(0.25, min(0.6, abs(e)))
        if e > 0, do: {:wheels, -w, w}, else: {:wheels, w, -w}
      else
        v = max(0.15, min(0.8, d * 3))
        {:wheels, v - 0.8 * e, v + 0.8 * e}
      end
    end
  end

  defp turn_to(th, target) do
    e = wrap(target - th)

    if abs(e) <= 0.04 do
      :aligned
    else
      w = max(0.12, min(0.5, abs(e)))
      if e > 0, do: {:wheels, -w, w}, else: {:wheels, w, -w}
    end
  end

  defp dist(x1, y1, x2, y2), do: :math.sqrt((x2 - x1) * (x2 - x1) + (y2 - y1) * (y2 - y1))

  defp wrap(a) do
    a = :math.fmod(a + :math.pi(), 2 * :math.pi())
    if a < 0, do: a + :math.pi(), else: a - :math.pi()
  end
end
