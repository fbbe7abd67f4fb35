defmodule TartarusLats.Deployment do
  @moduledoc """
  A LATS deployment on the emulator: the building (a `TartarusEmu.Topology`)
  brought to life by `TartarusEmu.Network`, virtual or on `:peer` nodes,
  with LATS's per-node setup hook (`node_setup/2`): every node gets a
  simulated BLE receiver (`TartarusLats.BeaconPlugin`, attached as
  `:beacon`) and a database agent (`TartarusLats.DatabaseAgent`, named
  `"lats-db"`). Beside it: a cloud host (`TartarusLats.Cloud`, in this VM)
  and the emulated world (`TartarusLats.World`, a value advanced here).

      dep = TartarusLats.Deployment.start(seed: 1, building: TartarusLats.Building.new(floors: 1, rows: 3, cols: 3))
      dep = TartarusLats.Deployment.run(dep, 60)
      TartarusLats.query(dep.hosts[:p1], :where_is, TartarusLats.World.tag(dep.world, :janitor))
      TartarusLats.Deployment.stop(dep)

  ## The driver

  `step/1` advances the world one second, writes every node's readings of
  that second into its receiver (`Tartarus.write_plugin/3`), and then drives
  every database agent through the phases of that second (`{:sense, t}`,
  `{:deliver, t, j}` while handshake messages flow, `{:tick, t}`). Each phase
  ends with a barrier: the agents cast their messages
  (`Tartarus.cast/3`) and say how many went where; the driver waits until
  every receiver (and the cloud) has taken them (`{:sync, n}` requests). So
  a run is deterministic for its seed, and between two steps the host
  stores are quiet: queries released then see a consistent snapshot.

  A node's host that goes away without the driver being told (`Tartarus.stop_host/1`, a
  crash) is found by the next step (its receiver or host is gone) and is dead to the
  driver from then on, as after `kill_node/2`: the run goes on without it.
  """

  alias TartarusLats.{Building, Cloud, DatabaseAgent, HM10, Radio, Region, World}

  defstruct building: nil,
            world: nil,
            rng: nil,
            readings: %{},
            net: nil,
            hosts: %{},
            cloud: nil,
            owns_cloud: false,
            expected: %{},
            uploads: 0,
            time: 0,
            record: nil,
            replay: nil,
            parsers: %{},
            down: MapSet.new(),
            feed: nil,
            input: %{records: 0, bad_records: 0, garbage_bytes: 0, other_devices: 0}

  @type t :: %__MODULE__{
          building: Building.t(),
          world: World.t(),
          rng: Radio.rng(),
          readings: %{Building.node_name() => map()},
          net: TartarusEmu.Network.t(),
          hosts: %{Building.node_name() => Tartarus.host()},
          cloud: Tartarus.host(),
          owns_cloud: boolean(),
          expected: %{Tartarus.host() => non_neg_integer()},
          uploads: non_neg_integer(),
          time: non_neg_integer(),
          record: IO.device() | nil,
          replay: TartarusLats.HM10.Recording.t() | nil,
          parsers: %{Building.node_name() => HM10.t()},
          down: MapSet.t(Building.node_name()),
          feed: %{pos_integer() => %{Building.node_name() => map()}} | nil,
          input: map()
        }

  @schema [
    seed: [type: :integer, default: 0, doc: "the world's seed"],
    world: [type: :any, doc: "a `TartarusLats.World` (default `World.new(building: building)`)"],
    building: [type: :any, doc: "a `TartarusLats.Building` (ignored when `:world` is given)"],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    group: [type: :pos_integer, default: 10, doc: "building nodes per BEAM node (peer mode)"],
    prefix: [type: :string, default: "lats", doc: "host name prefix"],
    centralized: [type: :boolean, default: true, doc: "database agents upload to the cloud"],
    data_dir: [type: :any, doc: "directory of the database agents' DETS logs (default none)"],
    timeout: [type: :pos_integer, default: 15, doc: "handshake timeout in world seconds"],
    cloud: [type: :any, doc: "a running host to put the cloud agent on (default a new host)"],
    record: [
      type: :any,
      doc:
        "an open IO device: every node's HM-10 output of every second is written to it (`TartarusLats.HM10.Recording`)"
    ],
    replay: [
      type: :any,
      doc:
        "a recording (`TartarusLats.HM10.Recording.read/1`): the receivers hear it, parsed by `TartarusLats.HM10`, instead of the simulated radio (the world still moves, for the ground truth)"
    ],
    feed: [
      type: :any,
      doc:
        "real readings, `%{second => %{node => %{tag => rssi}}}` (seconds from 1): each step gives the nodes that second's readings instead of the world's; the world does not move (`TartarusLats.Replay`)"
    ],
    calibration: [
      type: :any,
      doc:
        "the near/far thresholds (a `TartarusLats.Region` calibration) of every node (default: the radio model's)"
    ],
    corrections: [
      type: :any,
      default: %{},
      doc:
        "`%{node => {offset, slope}}`: each node's receiver correction, applied by its tracker (`TartarusLats.Replay.Calibration`)"
    ],
    tracker: [type: :any, default: [], doc: "more options of every node's `TartarusLats.Tracker`"],
    zone: [type: :any, default: [], doc: "options of every node's `TartarusLats.Zone`"]
  ]

  @doc """
  Starts a deployment. Options:

  #{Tartarus.Options.docs(@schema)}

  Raises `ArgumentError` on a bad option.
  """
  @spec start(keyword()) :: t()
  def start(opts \\ []) do
    opts = Tartarus.Options.validate!(opts, @schema, "TartarusLats.Deployment.start/1")

    world =
      Keyword.get_lazy(opts, :world, fn ->
        World.new(building: Keyword.get_lazy(opts, :building, &Building.new/0))
      end)

    building = world.building
    check_replay_nodes!(opts[:replay], building)

    # Peer mode makes this VM a distributed node; the cloud host, started here before the
    # network, must get its address under the node's final name.
    if opts[:mode] == :peer, do: :ok = TartarusTools.Peer.ensure_distributed()

    {cloud, owns} =
      case opts[:cloud] do
        nil ->
          {:ok, c} = Cloud.start("#{opts[:prefix]}#{System.unique_integer([:positive])}-cloud")
          {c, true}

        c ->
          {:ok, _} = Tartarus.create_static_agent(c, Cloud, nil, name: Cloud.agent_name())
          {c, false}
      end

    setup =
      node_setup(cloud, Keyword.put_new_lazy(opts, :calibration, fn -> calibration(world) end))

    {:ok, net} =
      TartarusEmu.Network.start(building,
        mode: opts[:mode],
        group: opts[:group],
        prefix: opts[:prefix],
        setup: setup
      )

    %__MODULE__{
      building: building,
      world: world,
      rng: Radio.seed(opts[:seed]),
      net: net,
      hosts: net.hosts,
      cloud: cloud,
      owns_cloud: owns,
      record: opts[:record],
      replay: opts[:replay],
      feed: opts[:feed]
    }
  end

  defp check_replay_nodes!(nil, _building), do: :ok

  defp check_replay_nodes!(replay, building) do
    known = MapSet.new(Building.nodes(building), &to_string/1)

    unknown =
      for {_t, nodes} <- replay,
          node <- Map.keys(nodes),
          not MapSet.member?(known, node),
          uniq: true,
          do: node

    if unknown != [],
      do:
        raise(
          ArgumentError,
          "the recording names nodes this building does not have: #{Enum.join(Enum.sort(unknown), ", ")}"
        )
  end

  defp calibration(world), do: Region.calibrate(tx_power: -59, exponent: world.radio.exponent)

  @doc """
  LATS's per-node setup hook for `TartarusEmu.Network.start/2`: attaches the
  receiver (`:beacon`) and creates the database agent, which knows its
  neighbours' hosts and the `cloud`. Options: `:centralized`, `:data_dir`,
  `:timeout`, `:corrections`, `:tracker`, `:zone` (see `start/1`) and `:calibration` (a
  `TartarusLats.Region` calibration).
  """
  @spec node_setup(Tartarus.host() | nil, keyword()) :: TartarusEmu.Network.setup()
  def node_setup(cloud, opts) do
    fn node, host, net ->
      neighbours =
        Map.new(Building.neighbours(net.topology, node), &{&1, TartarusEmu.Network.host(net, &1)})

      args = %{
        node: node,
        entrance: node in Building.entrances(net.topology),
        neighbours: neighbours,
        cloud: cloud,
        centralized: Keyword.get(opts, :centralized, true),
        data_dir: Keyword.get(opts, :data_dir),
        tracker:
          [
            calibration: Keyword.fetch!(opts, :calibration),
            correction: Map.get(Keyword.get(opts, :corrections, %{}), node, {0.0, 1.0})
          ] ++ Keyword.get(opts, :tracker, []),
        zone: Keyword.get(opts, :zone, []),
        timeout: Keyword.get(opts, :timeout, 15)
      }

      with :ok <- Tartarus.attach_plugin(host, :beacon, {TartarusLats.BeaconPlugin, node: node}) do
        Tartarus.create_static_agent(host, DatabaseAgent, args, name: DatabaseAgent.agent_name())
      end
    end
  end

  @doc """
  Restarts the host of `node` (what a node's reboot looks like): the
  network kills it and starts it again empty, and the setup hook attaches a
  new receiver and a new database agent (which reloads its log when the
  deployment has a `:data_dir`).
  """
  @spec restart_node(t(), Building.node_name()) :: t()
  def restart_node(%__MODULE__{} = dep, node), do: dep |> kill_node(node) |> revive_node(node)

  @doc """
  Kills the host of `node` (a node that dies): its receiver and database agent go with it.
  The driver goes on without it: it is not asked in the phases, messages sent to it are
  lost, queries that try to reach it find it unreachable. See `revive_node/2`.
  """
  @spec kill_node(t(), Building.node_name()) :: t()
  def kill_node(%__MODULE__{} = dep, node) do
    :ok = TartarusEmu.Network.kill_node(dep.net, node)
    %{dep | down: MapSet.put(dep.down, node), expected: Map.delete(dep.expected, dep.hosts[node])}
  end

  @doc """
  Starts a killed node's host again, empty, and runs the setup hook on it: a new receiver
  and a new database agent, which reloads its log and vectors when the deployment has a
  `:data_dir` (its tracker starts afresh: every tag beyond).
  """
  @spec revive_node(t(), Building.node_name()) :: t()
  def revive_node(%__MODULE__{} = dep, node) do
    :ok = TartarusEmu.Network.restart_node(dep.net, node)

    %{
      dep
      | down: MapSet.delete(dep.down, node),
        expected: Map.delete(dep.expected, dep.hosts[node])
    }
  end

  @doc "The nodes that are up (not killed), sorted."
  @spec live_nodes(t()) :: [Building.node_name()]
  def live_nodes(%__MODULE__{} = dep),
    do: dep.building |> Building.nodes() |> Enum.reject(&MapSet.member?(dep.down, &1))

  @doc "Runs `seconds` steps (see `step/1`)."
  @spec run(t(), non_neg_integer()) :: t()
  def run(%__MODULE__{} = dep, seconds),
    do: Enum.reduce(1..seconds//1, dep, fn _, d -> step(d) end)

  @doc """
  Advances the world by one second, writes the readings into the
  receivers and drives every database agent through that second (see the
  moduledoc). Returns the deployment with `time`, `world` and `readings`
  (this second's raw readings, `%{node => %{tag => rssi | :missing}}`)
  updated.
  """
  @spec step(t()) :: t()
  def step(%__MODULE__{feed: feed} = dep) when feed != nil do
    t = dep.time + 1
    readings = Map.get(feed, t, %{})
    sense_and_tick(%{dep | readings: readings, time: t}, t)
  end

  def step(%__MODULE__{} = dep) do
    {world, rng} = World.step(dep.world, dep.rng)
    # Drawn also when replaying, so the world (the ground truth) moves as when recorded.
    {readings, rng} = World.readings(world, rng)
    t = world.time
    if dep.record, do: record(dep.record, t, world, readings)
    {readings, dep} = if dep.replay, do: replayed(dep, t), else: {readings, dep}
    sense_and_tick(%{dep | world: world, rng: rng, readings: readings, time: t}, t)
  end

  # Second t on the nodes, once its readings are in `dep`: written, the nodes' sense phase
  # and its messages, then their tick.
  defp sense_and_tick(dep, t) do
    dep = dep |> write_readings(t) |> mark_down(dep)
    {dep, sent} = phase(dep, {:sense, t})
    dep = deliver(dep, t, sent, 1)
    {dep, _} = phase(dep, {:tick, t})
    dep
  end

  # Every node's scan of second t as its HM-10 prints it (tags it did not hear are absent).
  defp record(io, t, world, readings) do
    lines =
      for node <- Building.nodes(world.building) do
        beacons =
          for {tag, rssi} <- Enum.sort(Map.get(readings, node, %{})),
              is_integer(rssi),
              do: World.beacon(world, World.bearer_of(world, tag), rssi)

        HM10.Recording.line(t, node, HM10.encode_scan(beacons))
      end

    IO.binwrite(io, lines)
  end

  # What the receivers hear when replaying: each node's serial text of second t, fed to
  # that node's parser.
  defp replayed(dep, t) do
    serial = Map.get(dep.replay, t, %{})

    Enum.reduce(Building.nodes(dep.building), {%{}, dep}, fn node, {readings, dep} ->
      parser = Map.get(dep.parsers, node, HM10.new())
      {parser, events} = HM10.feed(parser, Map.get(serial, to_string(node), ""))

      dep = %{
        dep
        | parsers: Map.put(dep.parsers, node, parser),
          input: Enum.reduce(events, dep.input, &count_input/2)
      }

      {Map.put(readings, node, HM10.readings(events)), dep}
    end)
  end

  defp count_input({:beacon, _, _}, c), do: %{c | records: c.records + 1}
  defp count_input({:bad_record, _, _}, c), do: %{c | bad_records: c.bad_records + 1}
  defp count_input({:garbage, b}, c), do: %{c | garbage_bytes: c.garbage_bytes + byte_size(b)}
  defp count_input({:other_device, _, _}, c), do: %{c | other_devices: c.other_devices + 1}
  defp count_input(_scan_mark, c), do: c

  # What a node whose host is gone answers: the host is unknown, or it is stopping and its
  # plugins are already gone.
  @gone %{unknown_host: true, no_such_plugin: true, plugin_down: true}

  # Writes every live node's readings of second t into its receiver; returns the nodes whose
  # host or receiver is gone (a host stopped or crashed without the driver being told).
  defp write_readings(dep, t) do
    dep.hosts
    |> Enum.reject(fn {node, _host} -> MapSet.member?(dep.down, node) end)
    |> Task.async_stream(
      fn {node, host} ->
        heard =
          for {tag, rssi} <- Map.get(dep.readings, node, %{}),
              is_number(rssi),
              into: %{},
              do: {tag, rssi}

        {node, Tartarus.write_plugin(host, :beacon, {:readings, t, heard})}
      end,
      max_concurrency: 16,
      timeout: 60_000
    )
    |> Enum.flat_map(fn
      {:ok, {_node, :ok}} -> []
      {:ok, {node, {:error, reason}}} when is_map_key(@gone, reason) -> [node]
      {:ok, {node, {:error, {reason, _}}}} when is_map_key(@gone, reason) -> [node]
      {:ok, {node, other}} -> raise "LATS driver: receiver of #{node} failed: #{inspect(other)}"
    end)
  end

  # Nodes found gone are dead to the driver from now on, as if `kill_node/2` had been called:
  # not asked in the phases, nobody waits for messages sent to them.
  defp mark_down([], dep), do: dep

  defp mark_down(gone, dep) do
    hosts = MapSet.new(gone, &dep.hosts[&1])

    %{
      dep
      | down: Enum.into(gone, dep.down),
        expected: Map.reject(dep.expected, fn {h, _} -> MapSet.member?(hosts, h) end)
    }
  end

  # At most @deliveries deliveries a second; what is left waits for the next second's
  # first. The first always runs: the database agents decide their zones in it. The
  # one-holder protocol's floods (`TartarusLats.Zone`, `:one_holder`) need as many as the
  # building's diameter in hops, and a second's claims are arbitrated after its last.
  @deliveries 100
  defp deliver(dep, _t, 0, j) when j > 1, do: dep
  defp deliver(dep, _t, _sent, j) when j > @deliveries, do: dep

  defp deliver(dep, t, _sent, j) do
    {dep, sent} = phase(dep, {:deliver, t, j})
    deliver(dep, t, sent, j + 1)
  end

  # Sends `msg` to every database agent at once, then waits until every message the phase
  # cast has been taken (the barrier). Returns the deployment and the number of handshake
  # messages sent. Raises if an agent does not answer.
  defp phase(dep, msg) do
    live = Enum.reject(dep.hosts, fn {n, _host} -> MapSet.member?(dep.down, n) end)

    replies =
      live
      |> Enum.map(fn {_n, host} ->
        Task.async(fn -> Tartarus.request({DatabaseAgent.agent_name(), host}, msg, 60_000) end)
      end)
      |> Task.await_many(120_000)

    # A host that went away since the readings were written is dead from now on.
    gone =
      for {{n, _host}, {:error, reason}} <- Enum.zip(live, replies),
          reason == :unknown_host or match?({:unknown_host, _}, reason),
          do: n

    dep = mark_down(gone, dep)

    {expected, uploads, sent} =
      Enum.reduce(replies, {dep.expected, dep.uploads, 0}, fn
        {:ok, {:ok, %{sent: to, uploads: u}}}, {exp, ups, n} ->
          exp = Enum.reduce(to, exp, fn {h, k}, exp -> Map.update(exp, h, k, &(&1 + k)) end)
          {exp, ups + u, n + Enum.sum(Map.values(to))}

        {:error, reason}, acc when reason == :not_found or elem(reason, 0) == :unknown_host ->
          acc

        other, _ ->
          raise "LATS driver: a database agent failed #{inspect(msg)}: #{inspect(other)}"
      end)

    # Messages cast to a dead node are lost: nobody waits for them.
    dead = MapSet.new(dep.down, &dep.hosts[&1])
    expected = Map.reject(expected, fn {h, _} -> MapSet.member?(dead, h) end)
    changed = for {h, k} <- expected, Map.get(dep.expected, h) != k, do: {h, k}
    barrier(changed, if(uploads > dep.uploads, do: {dep.cloud, uploads}))
    {%{dep | expected: expected, uploads: uploads}, sent}
  end

  defp barrier(agents, cloud) do
    syncs =
      Enum.map(agents, fn {h, k} -> {DatabaseAgent.agent_name(), h, k} end) ++
        if(cloud, do: [{Cloud.agent_name(), elem(cloud, 0), elem(cloud, 1)}], else: [])

    syncs
    |> Enum.map(fn {name, host, k} ->
      Task.async(fn -> {host, Tartarus.request({name, host}, {:sync, k}, 60_000)} end)
    end)
    |> Task.await_many(120_000)
    |> Enum.each(fn
      {_host, {:ok, :ok}} -> :ok
      {_host, {:error, :not_found}} -> :ok
      {_host, {:error, {:unknown_host, _}}} -> :ok
      {host, other} -> raise "LATS driver: barrier at #{inspect(host)} failed: #{inspect(other)}"
    end)
  end

  @doc "Stops the network, and the cloud host if this deployment started it."
  @spec stop(t()) :: :ok
  def stop(%__MODULE__{} = dep) do
    TartarusEmu.Network.stop(dep.net)
    if dep.owns_cloud, do: Tartarus.stop_host(dep.cloud)
    :ok
  end
end
