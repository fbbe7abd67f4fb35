defmodule TartarusArena.RobotPlugin do
  @moduledoc """
  A robot of a shared arena as a `Tartarus.Plugin`: attach it to the robot's host, and
  agents on that host sense and drive the robot with `Tartarus.Agent.read/2` and
  `Tartarus.Agent.write/2`. A real robot's plugin answers the same reads and writes, so a
  robot host in emulation and a real one differ only in the plugin.

      Tartarus.attach_plugin(:santa, :robot,
        {TartarusArena.RobotPlugin, arena: arena_pid, robot: :santa})
      # inside an agent on :santa
      {:ok, %{ultrasonic: cm}} = Tartarus.Agent.read(:robot, :all)
      :ok = Tartarus.Agent.write(:robot, {:wheels, 0.5, 0.5})

  Options: `:arena` (a `TartarusArena.Server`, required), `:robot` (its id in the world,
  required).

  Reads: `:all` (or nil: every reading, see `TartarusArena.World`), `:ultrasonic`,
  `:colour`, `:light`, `:line`, `:bumped`, `:holding`, `:puck_in_gripper`.
  Writes: `{:wheels, left, right}` (fractions of top speed), `:stop`,
  `{:grip, :open | :close}`. `describe/1` reports the robot's tool (`:none`, `:pusher` or
  `:claws`) under `:capabilities`, so an agent can choose a robot by what it can do.
  """
  @behaviour Tartarus.Plugin

  alias TartarusArena.Server

  @reads [:all, :ultrasonic, :colour, :light, :line, :bumped, :holding, :puck_in_gripper]

  @impl true
  @doc "Checks the options and that the robot is in the arena."
  def init(opts) do
    with {:ok, arena} <- fetch(opts, :arena),
         {:ok, robot} <- fetch(opts, :robot),
         %{} = r <- Map.get(Server.world(arena).robots, robot) do
      {:ok, %{arena: arena, robot: robot, tool: r.tool}}
    else
      nil -> {:error, {:bad_option, :robot, "no such robot in the arena"}}
      error -> error
    end
  end

  defp fetch(opts, key) do
    case Keyword.fetch(opts, key) do
      {:ok, v} when v != nil -> {:ok, v}
      _ -> {:error, {:bad_option, key, "required"}}
    end
  end

  @impl true
  @doc "A robot: what it reads, what it takes, and its capabilities."
  def describe(s) do
    %{
      kind: :robot,
      robot: s.robot,
      capabilities: if(s.tool == :none, do: [:drive], else: [:drive, s.tool]),
      reads: @reads,
      writes: [:wheels, :stop, :grip]
    }
  end

  @impl true
  @doc "Senses (see the moduledoc)."
  def read(arg, s) when arg in [nil, :all], do: {:ok, Server.sense(s.arena, s.robot), s}

  def read(arg, s) when arg in @reads,
    do: {:ok, Map.fetch!(Server.sense(s.arena, s.robot), arg), s}

  def read(arg, s), do: {:error, {:bad_argument, arg}, s}

  @impl true
  @doc "Actuates (see the moduledoc)."
  def write({:wheels, l, r}, s) when is_number(l) and is_number(r) do
    :ok = Server.set_wheels(s.arena, s.robot, l, r)
    {:ok, s}
  end

  def write(:stop, s), do: write({:wheels, 0, 0}, s)

  def write({:grip, how}, s) when how in [:open, :close] do
    :ok = Server.grip(s.arena, s.robot, how)
    {:ok, s}
  end

  def write(arg, s), do: {:error, {:bad_argument, arg}, s}
end
