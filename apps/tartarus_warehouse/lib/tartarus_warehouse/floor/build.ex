defmodule TartarusWarehouse.Floor.Build do
  @moduledoc """
  Builds a warehouse floor on the emulator and takes it down: the network of §4.7.1
  (robot nodes, secondary nodes that only relay agents, the distributor's node) started
  with `TartarusEmu.Network`, a robot plugin on each robot host, and the distributor (or,
  for the baseline, the central server and its robot agents) created on it; what ran, read
  back from the robots and the network's event log. `TartarusWarehouse.Floor` drives it.

  ## Topology

  Node `"jd"` is the distributor's (the server's in the baseline); robots `"r1".."rk"` (R)
  are linked to each other (a full mesh up to 16 robots, else a ring with chords to the
  robots 4 and 16 places on) and to `"jd"` (the first 16); shared-resource nodes
  `"f1"..` (Φ, §4.7.1) and secondary nodes `"s1"..` (Σ) hang on two robots each (Φ node i
  on robots i and i + 2, Σ node i on robots i and i + 1, modulo the robots). Task agents
  move among robots (`TartarusWarehouse.Roam`).
  """

  alias Tartarus.Clock
  alias TartarusEmu.{Network, Topology}
  alias TartarusDashboard.Panel
  alias TartarusWarehouse.{Job, Robot}

  @typedoc "A started floor (see `start/3`)."
  @type ctx :: map()

  @doc """
  The floor's topology for `robots` robots, `secondary` relay nodes (Σ) and `phi`
  shared-resource nodes (Φ); with `robot_mesh` false no robot is linked to another, so
  robots meet only through Σ nodes (Σ node i on robots i and i + 1: with as many Σ nodes
  as robots, a ring) and `jd`.

      iex> t = TartarusWarehouse.Floor.Build.topology(3, 2)
      iex> {length(t.nodes), TartarusEmu.Topology.connected?(t)}
      {6, true}
      iex> t = TartarusWarehouse.Floor.Build.topology(60, 19, 20)
      iex> {length(t.nodes), TartarusEmu.Topology.connected?(t)}
      {100, true}
      iex> t = TartarusWarehouse.Floor.Build.topology(4, 4, 0, false)
      iex> Enum.filter(t.edges, &match?({"r" <> _, "r" <> _}, &1))
      []
  """
  @spec topology(pos_integer(), non_neg_integer(), non_neg_integer()) :: Topology.t()
  def topology(robots, secondary, phi \\ 0, robot_mesh \\ true) do
    rs = Enum.map(1..robots, &"r#{&1}")
    ss = if secondary > 0, do: Enum.map(1..secondary, &"s#{&1}"), else: []
    fs = if phi > 0, do: Enum.map(1..phi, &"f#{&1}"), else: []

    robot_edges = if robot_mesh, do: robot_edges(robots), else: []
    jd_edges = for i <- 1..min(robots, 16), do: {"jd", "r#{i}"}

    s_edges =
      for {s, i} <- Enum.with_index(ss),
          r <- Enum.uniq([rem(i, robots) + 1, rem(i + 1, robots) + 1]),
          do: {s, "r#{r}"}

    f_edges =
      for {f, i} <- Enum.with_index(fs),
          r <- Enum.uniq([rem(i, robots) + 1, rem(i + 2, robots) + 1]),
          do: {f, "r#{r}"}

    Topology.new(
      ["jd" | rs] ++ fs ++ ss,
      Enum.uniq(robot_edges ++ jd_edges ++ f_edges ++ s_edges)
    )
  end

  # With `phi_agents`, a rack (the static agent of §4.7.1) on each Φ node, f1 first, for
  # the agents' design (the central server's racks hold their programs a priori): the
  # addresses the task agents hand their code to; else none.
  defp racks(net, opts) do
    if opts[:phi_agents] and opts[:design] == :agents do
      for i <- 1..opts[:phi] do
        host = Network.host(net, "f#{i}")
        {:ok, id} = Tartarus.create_static_agent(host, TartarusWarehouse.Rack, %{rack: "f#{i}"})
        {id, host}
      end
    else
      []
    end
  end

  # Robots: a full mesh up to 16, else a ring with chords 4 and 16 places on (modulo the
  # robots: a circulant graph, the same seen from every robot).
  defp robot_edges(robots) do
    if robots <= 16,
      do: for(i <- 1..robots, j <- (i + 1)..robots//1, do: {"r#{i}", "r#{j}"}),
      else:
        for(
          i <- 1..robots,
          d <- [1, 4, 16],
          j = rem(i - 1 + d, robots) + 1,
          j != i,
          do: {"r#{min(i, j)}", "r#{max(i, j)}"}
        )
  end

  @doc """
  Starts the floor's network, a robot plugin on each robot host and the distributor (or
  the central server and its robot agents) for `world` and the checked `opts` (see
  `TartarusWarehouse.Floor.Options`). `owner` gets `{:warehouse_job_done, id, at_us}` for
  every job completed, `{:warehouse_distributor_failed, reason}` and
  `{:tartarus_removed, id, reason}` if the distributor fails. Returns the floor's context
  (`dref`: the distributor, `robot_hosts`, `net`, `log`, `status`, `design`, `guide`,
  `failover`, `data_dir`, `world`) for `publish/3`, `collect/4` and `stop/1`.
  """
  @spec start(Job.world(), keyword(), pid()) :: ctx()
  def start(world, opts, owner) do
    robots = opts[:robots]

    setup = fn node, host ->
      case node do
        "r" <> i ->
          i = String.to_integer(i)

          :ok =
            Tartarus.attach_plugin(
              host,
              :robot,
              {Robot,
               robot: node,
               reach: if(opts[:reach] == :all, do: :all, else: Map.get(opts[:reach], i, [])),
               scale: opts[:scale],
               pace: Enum.at(opts[:paces], i - 1, 1.0),
               jitter: opts[:jitter],
               seed: opts[:seed],
               off: i in opts[:standby]}
            )

          :ok

        _ ->
          :ok
      end
    end

    data_dir =
      if opts[:failover],
        do: Path.join(System.tmp_dir!(), "warehouse-jd-#{System.unique_integer([:positive])}")

    node_opts = if data_dir, do: %{"jd" => [data_dir: data_dir]}, else: %{}

    {:ok, net} =
      Network.start(topology(robots, opts[:secondary], opts[:phi], opts[:robot_mesh]),
        mode: opts[:mode],
        setup: setup,
        node_opts: node_opts,
        link: [latency_ms: opts[:latency_ms]]
      )

    try do
      start_agents(net, world, opts, owner, data_dir)
    rescue
      e ->
        Network.stop(net)
        if data_dir, do: File.rm_rf(data_dir)
        reraise e, __STACKTRACE__
    end
  end

  defp start_agents(net, world, opts, owner, data_dir) do
    robots = opts[:robots]
    design = opts[:design]
    {:ok, log} = TartarusEmu.Log.start(net)
    robot_hosts = for i <- 1..robots, into: %{}, do: {"r#{i}", Network.host(net, "r#{i}")}
    jd = Network.host(net, "jd")
    racks = racks(net, opts)

    {:ok, dist} =
      case design do
        :agents ->
          Tartarus.create_static_agent(
            jd,
            TartarusWarehouse.DistributorAgent,
            %{
              world: world,
              owner: owner,
              robots: robot_set(robot_hosts),
              all_robots: MapSet.new(Map.values(robot_hosts)),
              idle_ms: opts[:idle_ms],
              round: min(robots, 16),
              seed: opts[:seed],
              validate: opts[:failover],
              guide: if(opts[:guide], do: robot_span(robots)),
              service_ms: opts[:service_ms],
              continue: opts[:continue],
              max_pending_tasks: opts[:max_pending_tasks],
              racks: racks
            },
            # told `{:tartarus_removed, id, reason}` if it is removed
            owner: owner
          )

        :central ->
          agents =
            Map.new(robot_hosts, fn {name, host} ->
              {:ok, id} =
                Tartarus.create_static_agent(host, TartarusWarehouse.CentralRobot, %{
                  robot: name,
                  server: nil
                })

              {name, {id, host}}
            end)

          {:ok, sid} =
            Tartarus.create_static_agent(
              jd,
              TartarusWarehouse.Central,
              %{
                world: world,
                owner: owner,
                robots: agents,
                service_ms: opts[:service_ms],
                max_pending_tasks: opts[:max_pending_tasks]
              },
              owner: owner
            )

          Enum.each(agents, fn {_, a} -> :ok = Tartarus.post(a, {:server, {sid, jd}}) end)
          {:ok, sid}
      end

    %{
      dref: {dist, jd},
      robot_hosts: robot_hosts,
      net: net,
      log: log,
      status: opts[:status],
      design: design,
      guide: opts[:guide],
      failover: opts[:failover],
      data_dir: data_dir,
      world: world,
      racks: racks
    }
  end

  @doc """
  Publishes the floor (its network, robot hosts, design, start time `t0` in µs) and its
  `jobs` submitted so far to the status table of the dashboard's panel
  (`TartarusWarehouse.Panel`), if the floor has one.
  """
  @spec publish(ctx(), non_neg_integer(), integer()) :: :ok
  def publish(ctx, jobs, t0) do
    Panel.publish(ctx.status, fn t ->
      :ets.insert(t, [
        {:floor,
         %{
           net: ctx.net,
           robot_hosts: ctx.robot_hosts,
           design: ctx.design,
           guide: ctx.guide,
           t0_us: t0
         }},
        {:jobs, jobs, 0}
      ])
    end)

    :ok
  end

  @doc """
  What ran on the floor: the robots' histories (`history`, see `TartarusWarehouse.Robot`),
  the jobs submitted (`ids`) and their completions (`completed`: id => µs), `timed_out`
  (not completed), `t0_us`, `makespan_ms` (from `t0` to the last completion), `robots`
  (names, in order), the network's totals from its event log (`migrations`, `bytes`,
  `messages`), the agents' arrivals per topology node (`arrivals_by_node`), the code each
  rack received (`rack_codes`: rack => `[{agent, task, program}]`, in order; `%{}` without
  `phi_agents`), and `service_log`: what the distributor or the central server served
  (`{arrived, started, done}`, monotonic µs; `mono_offset_us` is monotonic minus system
  time, to put them on the histories' clock; see `TartarusWarehouse.Service`).
  """
  @spec collect(ctx(), [term()], %{term() => integer()}, integer()) :: map()
  def collect(ctx, ids, completed, t0) do
    :ok = TartarusEmu.Log.sync(ctx.log)
    totals = TartarusEmu.Log.totals(ctx.log)

    history = Robot.history(ctx.robot_hosts)

    # What the distributor (or the central server) served, and when (monotonic µs).
    service_log =
      case Tartarus.request(ctx.dref, :status, 30_000) do
        {:ok, %{service_log: log}} -> log
        _ -> []
      end

    last = completed |> Map.values() |> Enum.max(fn -> t0 end)

    rack_codes =
      for {rack, i} <- Enum.with_index(Map.get(ctx, :racks, []), 1),
          {:ok, codes} = Tartarus.request(rack, :received, 30_000),
          into: %{},
          do: {"f#{i}", codes}

    %{
      design: ctx.design,
      history: history,
      jobs: ids,
      completed: completed,
      timed_out: Enum.reject(ids, &Map.has_key?(completed, &1)),
      t0_us: t0,
      makespan_ms: (last - t0) / 1000,
      robots:
        Map.keys(ctx.robot_hosts)
        |> Enum.sort_by(&String.to_integer(String.slice(&1, 1..-1//1))),
      migrations: Map.get(totals, :departures, 0),
      arrivals_by_node: arrivals_by_node(ctx),
      rack_codes: rack_codes,
      bytes: Map.get(totals, :bytes, 0),
      messages: Map.get(totals, :messages, 0),
      service_log: service_log,
      # monotonic µs minus system µs: the service log's times on the histories' clock
      mono_offset_us: Clock.monotonic_time(:microsecond) - Clock.system_time(:microsecond)
    }
  end

  # Agents' arrivals per topology node (which nodes the agents crossed).
  defp arrivals_by_node(ctx) do
    for {host, counters} <- TartarusEmu.Log.counts(ctx.log).hosts,
        n = Map.get(counters, :arrivals, 0),
        n > 0,
        into: %{},
        do: {Network.topo_node(ctx.net, host) || inspect(host), n}
  end

  @doc "Stops the floor: its panel entry, event log, network and journal directory."
  @spec stop(ctx()) :: :ok
  def stop(ctx) do
    Panel.publish(ctx.status, &:ets.delete(&1, :floor))
    TartarusEmu.Log.stop(ctx.log)
    Network.stop(ctx.net)
    if ctx.data_dir, do: File.rm_rf(ctx.data_dir)
    :ok
  end

  # How agents tell robots: by name prefix ("emu<tag>-r"), when every robot's name has it
  # (nothing that grows with the robots travels with them), else the set of robot hosts.
  defp robot_set(robot_hosts) do
    {name, _} = robot_hosts["r1"]

    with true <- is_binary(name) and String.ends_with?(name, "-r1"),
         prefix = String.slice(name, 0..-2//1),
         true <-
           Enum.all?(robot_hosts, fn {r, {n, _}} -> n == prefix <> String.slice(r, 1..-1//1) end) do
      {:prefix, prefix}
    else
      _ -> MapSet.new(Map.values(robot_hosts))
    end
  end

  # The hops between the two farthest robots (a full mesh: 1).
  defp robot_span(robots) when robots <= 16, do: 1

  # How far a field must reach to cover every robot from any robot: the diameter of the
  # robots' own graph (circulant, so any robot's eccentricity; the other hosts only add
  # shortcuts, never length).
  defp robot_span(robots) do
    robot_topo = Topology.new(Enum.map(1..robots, &"r#{&1}"), robot_edges(robots))
    robot_topo |> Topology.distances("r1") |> Map.values() |> Enum.max()
  end
end
