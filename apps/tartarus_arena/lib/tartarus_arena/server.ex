defmodule TartarusArena.Server do
  @moduledoc """
  The one process that owns a shared arena: a thin `GenServer` around a
  `TartarusArena.World`, so that several robot hosts (each with a
  `TartarusArena.RobotPlugin` naming its robot) sense and drive robots in the same world.

  Time advances only by `step/2` (a driver, e.g. a scenario, steps it: deterministic) or,
  with the `:tick_ms` option, by one `:dt` step every `tick_ms` of `Tartarus.Clock` time (a
  live arena for interactive runs; not deterministic in the order commands arrive).

      iex> {:ok, pid} = TartarusArena.Server.start_link(world: TartarusArena.World.new(noise: :none) |> TartarusArena.World.add_robot(:r, x: 1, y: 1))
      iex> :ok = TartarusArena.Server.set_wheels(pid, :r, 1.0, 1.0)
      iex> :ok = TartarusArena.Server.step(pid, 50)
      iex> {x, _, _} = TartarusArena.Server.pose(pid, :r)
      iex> Float.round(x, 3)
      1.25
      iex> GenServer.stop(pid)
      :ok
  """
  use GenServer

  alias Tartarus.Clock
  alias TartarusArena.World

  @typedoc "A server: pid or registered name."
  @type server :: GenServer.server()

  @doc """
  Starts the server. Options: `:world` (required), `:dt` (step length, default 0.02 s),
  `:tick_ms` (step by itself every `tick_ms`; default nil: only `step/2` advances time),
  `:name`.
  """
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts) do
    case Keyword.fetch(opts, :world) do
      {:ok, %World{}} ->
        :ok

      other ->
        raise ArgumentError,
              "invalid options given to TartarusArena.Server.start_link/1 for key [:world]: expected a TartarusArena.World, got: #{inspect(other)}"
    end

    GenServer.start_link(__MODULE__, opts, Keyword.take(opts, [:name]))
  end

  @doc "The current world."
  @spec world(server()) :: World.t()
  def world(server), do: GenServer.call(server, :world)

  @doc "Applies a pure function to the world (set-up: add pucks, switch the light, ...)."
  @spec update(server(), (World.t() -> World.t())) :: :ok
  def update(server, fun) when is_function(fun, 1), do: GenServer.call(server, {:update, fun})

  @doc "Advances the world by `n` steps of `dt`."
  @spec step(server(), pos_integer()) :: :ok
  def step(server, n \\ 1) when is_integer(n) and n > 0, do: GenServer.call(server, {:step, n})

  @doc "Sets a robot's wheel command (fractions of top speed, clipped to [-1, 1])."
  @spec set_wheels(server(), World.id(), number(), number()) :: :ok
  def set_wheels(server, id, l, r), do: update(server, &World.set_wheels(&1, id, l, r))

  @doc "Opens or closes a robot's claws."
  @spec grip(server(), World.id(), :open | :close) :: :ok
  def grip(server, id, how), do: update(server, &World.grip(&1, id, how))

  @doc "Switches the light."
  @spec set_light(server(), :on | :off) :: :ok
  def set_light(server, state), do: update(server, &World.set_light(&1, state))

  @doc "Reads a robot's sensors (`TartarusArena.World.sense/2`)."
  @spec sense(server(), World.id()) :: World.readings()
  def sense(server, id), do: GenServer.call(server, {:sense, id})

  @doc "A robot's pose."
  @spec pose(server(), World.id()) :: World.pose()
  def pose(server, id), do: World.pose(world(server), id)

  @impl true
  def init(opts) do
    tick = Keyword.get(opts, :tick_ms)
    tick = if is_integer(tick) and tick > 0, do: tick
    s = %{world: Keyword.fetch!(opts, :world), dt: Keyword.get(opts, :dt, 0.02), tick: tick}
    {:ok, if(tick, do: arm_tick(s, Clock.monotonic_time(:millisecond) + tick), else: s)}
  end

  @impl true
  def handle_call(:world, _from, s), do: {:reply, s.world, s}

  def handle_call({:update, fun}, _from, s) do
    {:reply, :ok, %{s | world: fun.(s.world)}}
  rescue
    e -> {:reply, {:error, Exception.message(e)}, s}
  end

  def handle_call({:step, n}, _from, s) do
    world = Enum.reduce(1..n, s.world, fn _, w -> World.step(w, %{}, s.dt) end)
    {:reply, :ok, %{s | world: world}}
  end

  def handle_call({:sense, id}, _from, s) do
    if Map.has_key?(s.world.robots, id) do
      {readings, world} = World.sense(s.world, id)
      {:reply, readings, %{s | world: world}}
    else
      {:reply, {:error, {:no_such_robot, id}}, s}
    end
  end

  @impl true
  def handle_info({:tick, at}, %{next_tick: at} = s),
    do: handle_info(:tick, arm_tick(s, at + s.tick))

  def handle_info(:tick, s), do: {:noreply, %{s | world: World.step(s.world, %{}, s.dt)}}
  def handle_info(_msg, s), do: {:noreply, s}

  # One tick every `tick` ms at fixed instants of Tartarus.Clock (as :timer.send_interval/2:
  # a late tick does not delay the next ones). A relative delay, not `abs: true`: the
  # monotonic time may be negative.
  defp arm_tick(s, at) do
    Clock.send_after(self(), {:tick, at}, max(at - Clock.monotonic_time(:millisecond), 0))
    Map.put(s, :next_tick, at)
  end
end
