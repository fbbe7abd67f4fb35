defmodule TartarusLats.WorldServer do
  @moduledoc """
  The emulated physical world as a process: a `TartarusLats.World` and its
  random state, advanced one second at a time by the scenario driver, and
  asked by every node's simulated receiver (`TartarusLats.BeaconPlugin`)
  what it hears now.

  The world never advances by itself: `step/1` moves the bearers and draws
  every node's readings for the new second, so a run is a pure function of
  the seed, however fast the hosts are. Readings are drawn for all nodes at
  once in node order (as `TartarusLats.Sim` does), so the order in which
  receivers ask does not change what they hear.

      {:ok, w} = TartarusLats.WorldServer.start_link(seed: 1)
      :ok = TartarusLats.WorldServer.step(w)
      {:ok, readings} = TartarusLats.WorldServer.readings(w, :p3, 1)
  """
  use GenServer

  alias TartarusLats.{Radio, World}

  @doc """
  Starts a world. Options: `:seed` (integer, default 0), `:world` (a
  `TartarusLats.World`, default `TartarusLats.World.new/0`), `:name`.
  """
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts \\ []) do
    gen = if opts[:name], do: [name: opts[:name]], else: []
    GenServer.start_link(__MODULE__, opts, gen)
  end

  @doc "Stops the world."
  @spec stop(GenServer.server()) :: :ok
  def stop(server), do: GenServer.stop(server)

  @doc "Advances the world by one second and draws the readings of that second."
  @spec step(GenServer.server()) :: :ok
  def step(server), do: GenServer.call(server, :step, 60_000)

  @doc """
  What `node` hears in second `t`: `{:ok, %{tag => rssi}}` (tags not heard
  are left out), or `{:error, {:not_now, t, now}}` if the world is at
  another second.
  """
  @spec readings(GenServer.server(), TartarusLats.Building.node_name(), integer()) ::
          {:ok, map()} | {:error, term()}
  def readings(server, node, t), do: GenServer.call(server, {:readings, node, t}, 60_000)

  @doc "The world value now (for ground truth)."
  @spec world(GenServer.server()) :: World.t()
  def world(server), do: GenServer.call(server, :world, 60_000)

  @doc "All nodes' readings of the current second, `%{node => %{tag => rssi | :missing}}`."
  @spec all_readings(GenServer.server()) :: map()
  def all_readings(server), do: GenServer.call(server, :all_readings, 60_000)

  @impl true
  def init(opts) do
    world = Keyword.get_lazy(opts, :world, &World.new/0)
    {:ok, %{world: world, rng: Radio.seed(Keyword.get(opts, :seed, 0)), readings: %{}}}
  end

  @impl true
  def handle_call(:step, _from, s) do
    {world, rng} = World.step(s.world, s.rng)
    {readings, rng} = World.readings(world, rng)
    {:reply, :ok, %{s | world: world, rng: rng, readings: readings}}
  end

  def handle_call({:readings, node, t}, _from, s) do
    if t == s.world.time do
      heard =
        for {tag, rssi} <- Map.get(s.readings, node, %{}),
            is_number(rssi),
            into: %{},
            do: {tag, rssi}

      {:reply, {:ok, heard}, s}
    else
      {:reply, {:error, {:not_now, t, s.world.time}}, s}
    end
  end

  def handle_call(:world, _from, s), do: {:reply, s.world, s}
  def handle_call(:all_readings, _from, s), do: {:reply, s.readings, s}
end
