defmodule TartarusLats.Deployment do
  @moduledoc """
  A LATS deployment on the platform: one host per node of a
  `TartarusLats.Building`, linked as the building's adjacency, each with a
  simulated BLE receiver (`TartarusLats.BeaconPlugin`, attached as
  `:beacon`) and a database agent (`TartarusLats.DatabaseAgent`, named
  `"lats-db"`); a cloud host (`TartarusLats.Cloud`); and the emulated world
  (`TartarusLats.WorldServer`) that the receivers listen to.

      dep = TartarusLats.Deployment.start(seed: 1, building: TartarusLats.Building.new(floors: 1, rows: 3, cols: 3))
      dep = TartarusLats.Deployment.run(dep, 60)
      TartarusLats.query(dep.hosts[:p1], :where_is, TartarusLats.World.tag(dep.world_value, :janitor))
      TartarusLats.Deployment.stop(dep)

  ## The driver

  `step/1` advances the world one second and then drives every database
  agent through the phases of that second (`{:sense, t}`, `{:deliver, t}`
  while handshake messages flow, `{:tick, t}`), waiting for all answers of
  a phase before the next (a barrier). So a run is deterministic for its
  seed, and between two steps the host stores are quiet: queries released
  then see a consistent snapshot.

  ## Hosts

  Hosts are virtual (many hosts in this VM), started with
  `Tartarus.start_host/2` and linked with `Tartarus.connect/2`; host names
  are `"<prefix>-<node>"` (default prefix `"lats"`) and the cloud is
  `"<prefix>-cloud"`. Options `:hosts` (`%{node => host}`, hosts already
  running elsewhere, e.g. on `:peer` nodes started by `TartarusEmu.Network`)
  and `:cloud` (a running host) make it use those instead; it then only
  attaches the plugins and creates the agents.
  """

  alias TartarusLats.{Building, Cloud, DatabaseAgent, Region, World, WorldServer}

  defstruct building: nil,
            world: nil,
            world_value: nil,
            hosts: %{},
            cloud: nil,
            prefix: "lats",
            owned_hosts: [],
            time: 0

  @type t :: %__MODULE__{
          building: Building.t(),
          world: pid(),
          world_value: World.t() | nil,
          hosts: %{Building.node_name() => Tartarus.host()},
          cloud: Tartarus.host() | nil,
          prefix: String.t(),
          owned_hosts: [Tartarus.host()],
          time: non_neg_integer()
        }

  @doc """
  Starts a deployment. Options:

    * `:seed` - the world's seed (default 0);
    * `:world` - a `TartarusLats.World` (default `World.new(building: building)`);
    * `:building` - default `TartarusLats.Building.new/0` (ignored when `:world` is given);
    * `:prefix` - host name prefix (default `"lats"`);
    * `:centralized` - database agents upload to the cloud (Scenario 1; default true);
    * `:data_dir` - directory of the database agents' DETS logs (default none);
    * `:timeout` - handshake timeout in world seconds (default 15);
    * `:hosts`, `:cloud` - use running hosts (see the moduledoc).
  """
  @spec start(keyword()) :: t()
  def start(opts \\ []) do
    world =
      Keyword.get_lazy(opts, :world, fn ->
        World.new(building: Keyword.get_lazy(opts, :building, &Building.new/0))
      end)

    building = world.building
    prefix = Keyword.get(opts, :prefix, "lats")
    {:ok, server} = GenServer.start(WorldServer, seed: Keyword.get(opts, :seed, 0), world: world)
    nodes = Building.nodes(building)

    {hosts, owned} =
      case Keyword.get(opts, :hosts) do
        nil ->
          hosts =
            Map.new(nodes, fn n ->
              {:ok, h} = Tartarus.start_host("#{prefix}-#{n}")
              {n, h}
            end)

          for n <- nodes,
              m <- Building.neighbours(building, n),
              n < m,
              do: :ok = Tartarus.connect(hosts[n], hosts[m])

          {hosts, Map.values(hosts)}

        hosts ->
          {hosts, []}
      end

    {cloud, owned} =
      case Keyword.get(opts, :cloud) do
        nil ->
          {:ok, c} = Cloud.start("#{prefix}-cloud")
          {c, [c | owned]}

        c ->
          {:ok, _} = Tartarus.create_static_agent(c, Cloud, nil, name: Cloud.agent_name())
          {c, owned}
      end

    cal = Region.calibrate(tx_power: -59, exponent: world.radio.exponent)

    for n <- nodes do
      :ok =
        Tartarus.attach_plugin(
          hosts[n],
          :beacon,
          {TartarusLats.BeaconPlugin, node: n, world: server}
        )

      {:ok, _} = start_database(hosts[n], n, building, hosts, cloud, cal, opts)
    end

    %__MODULE__{
      building: building,
      world: server,
      world_value: world,
      hosts: hosts,
      cloud: cloud,
      prefix: prefix,
      owned_hosts: owned
    }
  end

  @doc false
  def start_database(host, node, building, hosts, cloud, cal, opts) do
    args = %{
      node: node,
      neighbours: Map.new(Building.neighbours(building, node), &{&1, hosts[&1]}),
      cloud: cloud,
      centralized: Keyword.get(opts, :centralized, true),
      data_dir: Keyword.get(opts, :data_dir),
      tracker: [calibration: cal],
      timeout: Keyword.get(opts, :timeout, 15)
    }

    Tartarus.create_static_agent(host, DatabaseAgent, args, name: DatabaseAgent.agent_name())
  end

  @doc """
  Restarts the host of `node` (stop, start, re-link, re-attach the receiver,
  new database agent): what a node's reboot looks like. With a `:data_dir`
  (same options as `start/1`) the database agent reloads its log.
  """
  @spec restart_node(t(), Building.node_name(), keyword()) :: :ok
  def restart_node(%__MODULE__{} = dep, node, opts \\ []) do
    host = dep.hosts[node]
    :ok = Tartarus.stop_host(host)
    {:ok, ^host} = Tartarus.start_host(elem(host, 0))

    for m <- Building.neighbours(dep.building, node),
        do: :ok = Tartarus.connect(host, dep.hosts[m])

    :ok =
      Tartarus.attach_plugin(
        host,
        :beacon,
        {TartarusLats.BeaconPlugin, node: node, world: dep.world}
      )

    cal = Region.calibrate(tx_power: -59, exponent: dep.world_value.radio.exponent)
    {:ok, _} = start_database(host, node, dep.building, dep.hosts, dep.cloud, cal, opts)
    :ok
  end

  @doc "Runs `seconds` steps (see `step/1`)."
  @spec run(t(), non_neg_integer()) :: t()
  def run(%__MODULE__{} = dep, seconds),
    do: Enum.reduce(1..seconds//1, dep, fn _, d -> step(d) end)

  @doc """
  Advances the world by one second and drives every database agent through
  that second (see the moduledoc). Returns the deployment with `time` and
  `world_value` updated.
  """
  @spec step(t()) :: t()
  def step(%__MODULE__{} = dep) do
    :ok = WorldServer.step(dep.world)
    t = dep.time + 1
    sent = phase(dep, {:sense, t})
    deliver(dep, t, sent, 10)
    phase(dep, {:tick, t})
    %{dep | time: t, world_value: WorldServer.world(dep.world)}
  end

  defp deliver(_dep, _t, 0, _n), do: :ok
  defp deliver(_dep, _t, _sent, 0), do: :ok
  defp deliver(dep, t, _sent, n), do: deliver(dep, t, phase(dep, {:deliver, t}), n - 1)

  # Sends `msg` to every database agent at once; returns the number of handshake
  # messages they posted. Raises if an agent does not answer.
  defp phase(dep, msg) do
    dep.hosts
    |> Enum.map(fn {_n, host} ->
      Task.async(fn -> Tartarus.request({DatabaseAgent.agent_name(), host}, msg, 60_000) end)
    end)
    |> Task.await_many(120_000)
    |> Enum.reduce(0, fn
      {:ok, {:ok, n}}, acc -> acc + n
      {:error, :not_found}, acc -> acc
      other, _ -> raise "LATS driver: a database agent failed #{inspect(msg)}: #{inspect(other)}"
    end)
  end

  @doc "Stops the hosts this deployment started and the world."
  @spec stop(t()) :: :ok
  def stop(%__MODULE__{} = dep) do
    Enum.each(dep.owned_hosts, &Tartarus.stop_host/1)
    if Process.alive?(dep.world), do: GenServer.stop(dep.world)
    :ok
  end
end
