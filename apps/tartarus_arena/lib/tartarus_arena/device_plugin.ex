defmodule TartarusArena.DevicePlugin do
  @moduledoc """
  One device of an arena robot as a `Tartarus.Plugin` of its own: an ultrasonic sensor,
  a colour sensor, the two light sensors, the two line sensors, or the motors (with their
  rotation sensors). `TartarusArena.RobotPlugin` is the whole robot behind one name; this
  is the same robot cut into the devices a LEGO NXT brick has on its ports, so a host can
  list them one by one and an agent can choose a robot by what its devices can do.

      Tartarus.attach_plugin(:pc1, :sonar,
        {TartarusArena.DevicePlugin, arena: arena, robot: :santa, device: :ultrasonic})
      # inside an agent on :pc1
      {:ok, cm} = Tartarus.Agent.read(:sonar)

  Options: `:arena` (a `TartarusArena.Server`, required), `:robot` (its id in the world,
  required), `:device` (required): one of #{inspect([:ultrasonic, :colour, :light, :line, :motors])}.

  | device | reads | writes | capabilities |
  |---|---|---|---|
  | `:ultrasonic` | nil: cm 0..200 | - | `[:ultrasonic]` |
  | `:colour` | nil: 0..9 | - | `[:colour]` |
  | `:light` | nil: `{left, right}` 0..100 | - | `[:light]` |
  | `:line` | nil: `{left, right}` 0..100 | - | `[:line]` |
  | `:motors` | `:odometry` (or nil): `{x, y, heading}` | `{:wheels, l, r}`, `:stop` | `[:drive, :odometry]` |

  Odometry is the pose integrated from the turns of the wheels, which the NXT's motors
  count; the arena's wheels do not slip, so it is the robot's true pose (a real robot's
  drifts).
  """
  @behaviour Tartarus.Plugin

  alias TartarusArena.Server

  @devices [:ultrasonic, :colour, :light, :line, :motors]

  @doc "The devices this plugin can stand for."
  @spec devices() :: [atom()]
  def devices, do: @devices

  @impl true
  @doc "Checks the options and that the robot is in the arena."
  def init(opts) do
    with {:ok, arena} <- fetch(opts, :arena),
         {:ok, robot} <- fetch(opts, :robot),
         {:ok, device} <- fetch(opts, :device),
         true <- device in @devices || {:bad_device, device},
         %{} <- Map.get(Server.world(arena).robots, robot) do
      {:ok, %{arena: arena, robot: robot, device: device}}
    else
      nil ->
        {:error, {:bad_option, :robot, "no such robot in the arena"}}

      {:bad_device, d} ->
        {:error,
         {:bad_option, :device, "expected one of #{inspect(@devices)}, got: #{inspect(d)}"}}

      error ->
        error
    end
  end

  defp fetch(opts, key) do
    case Keyword.fetch(opts, key) do
      {:ok, v} when v != nil -> {:ok, v}
      _ -> {:error, {:bad_option, key, "required"}}
    end
  end

  @impl true
  @doc "The device: its kind, reads, writes and capabilities (see the moduledoc)."
  def describe(%{device: :motors} = s) do
    %{
      kind: :motors,
      robot: s.robot,
      reads: [:odometry],
      writes: [:wheels, :stop],
      capabilities: [:drive, :odometry]
    }
  end

  def describe(s),
    do: %{kind: :sensor, robot: s.robot, reads: [nil], writes: [], capabilities: [s.device]}

  @impl true
  @doc "Reads the device (see the moduledoc)."
  def read(arg, %{device: :motors} = s) when arg in [nil, :odometry],
    do: {:ok, Server.pose(s.arena, s.robot), s}

  def read(nil, s), do: {:ok, Map.fetch!(Server.sense(s.arena, s.robot), s.device), s}
  def read(arg, s), do: {:error, {:bad_argument, arg}, s}

  @impl true
  @doc "Drives the motors; sensors take no writes."
  def write({:wheels, l, r}, %{device: :motors} = s) when is_number(l) and is_number(r) do
    :ok = Server.set_wheels(s.arena, s.robot, l, r)
    {:ok, s}
  end

  def write(:stop, %{device: :motors} = s), do: write({:wheels, 0, 0}, s)
  def write(arg, s), do: {:error, {:bad_argument, arg}, s}
end
