defmodule TartarusEmu.Walk do
  @moduledoc """
  The generic scenario behind `mix tartarus.emu`: mobile agents walking a topology
  (`:random` or `:conscientious`) while links come and go.

  ## Step model (deterministic)

  Steps are rounds, not wall-clock ticks. In step `k` the runner:

    1. applies the network dynamics (`p > 0`): every topology node breaks off or reconnects
       with probability `p` (`TartarusEmu.Dynamics`, carried out by
       `TartarusEmu.Network.apply_dynamics/2`);
    2. sends `{:emu_step, k}` to every agent (`TartarusEmu.Network.broadcast/2`);
    3. waits until every agent reached has made its one move (or failed it) and reported
       (`TartarusEmu.Walker`); nothing else changes the network meanwhile;
    4. advances the log's step clock (`TartarusEmu.Log.tick/1`) and records the series.

  During a step every agent sees a fixed network and decides with its own seeded random
  state, so the walk of every agent, and therefore every series below except the byte
  counts (host names and agent ids differ in length between runs), is the same for the
  same seed, whatever the scheduling: agents still move concurrently within a step.

  ## Options (from `TartarusEmu.Scenario.run/2` or the mix task)

    * `:topology` - `"grid"` (default), `"ring"`, `"line"`, `"random"` (random geometric,
      connected), a path to a topology file (`TartarusEmu.Topology`), or a
      `%TartarusEmu.Topology{}`;
    * `:hosts` (default 16; ignored for files and structs), `:agents` (default 4);
    * `:mode` - `:virtual` (default) or `:peer`; `:group` - hosts per peer node;
    * `:strategy` - `:random` (default) or `:conscientious`;
    * `:p` - node dynamism per step (default 0); `:latency_ms`, `:loss` - per link;
    * `:until_covered` - stop once every host was visited;
    * `:step_timeout_ms` - how long a step waits for its agents (default 60 s);
    * `:migration_timeout_ms` - the hosts' `:migration_timeout` (default 60 s: with
      100,000 agents moving at once on two cores, a hand-off can wait longer than the
      platform's default 5 s for its destination host, and then fails);
    * `:keep_events` - keep raw events in the log (for `log_events.csv`).

  ## Series

  `coverage` (fraction of hosts visited so far), `migrations` (per step), `failed_moves`
  (per step), `down_nodes` (isolated now), `bytes` (per step, hand-offs incl. code).

  ## Summary keys

  `hosts, agents, steps, mode, strategy, topology, seed, p, migrations, migrations_per_s,
  failed_moves, messages, bytes, energy_mj, energy_params, wall_ms, steps_ms, coverage,
  covered_at_step, memory_mb, processes, lost_reports, network_ms, agents_ms`; `wall_ms` is
  the run's real time from the first step's start to the last step's end (setup excluded,
  the pauses of `:step_ms` between steps included), `steps_ms` the time inside the steps
  alone, over which `migrations_per_s` is counted; `network_ms` and `agents_ms` are the
  setup times of the network and of the agents.
  """

  @behaviour TartarusEmu.Scenario

  alias TartarusEmu.{Dynamics, Energy, Log, Network, Topology}
  alias TartarusTools.Series
  alias Tartarus.Clock
  require Tartarus.Clock

  @schema [
    topology: [type: :any, default: "grid", doc: "grid, ring, line, random, a file or a topology"],
    hosts: [type: :pos_integer, default: 16, doc: "hosts (generated topologies)"],
    agents: [type: :pos_integer, default: 4, doc: "walking agents"],
    steps: [type: :pos_integer, default: 100, doc: "steps at most"],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    group: [type: :pos_integer, default: 1, doc: "hosts per BEAM node in peer mode"],
    strategy: [type: {:in, [:random, :conscientious]}, default: :random, doc: "how agents walk"],
    p: [type: :probability, default: 0, doc: "node dynamism per step"],
    until_covered: [type: :boolean, default: false, doc: "stop once every host was visited"],
    keep_events: [type: :boolean, default: false, doc: "keep raw events in the log"],
    step_timeout_ms: [type: :pos_integer, default: 60_000, doc: "wait for a step's agents"],
    migration_timeout_ms: [type: :pos_integer, default: 60_000, doc: "hosts' hand-off timeout"]
  ]

  @doc """
  The walk's options with their defaults (a `Tartarus.Options` schema; `mix tartarus.emu`
  reads its defaults here):

  #{Tartarus.Options.docs(@schema)}
  """
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @impl true
  def name, do: "walk"

  @doc """
  Runs the scenario (options of `TartarusEmu.Scenario.run/2` and of this module) and returns
  its summary. A virtual-mode run that needs more processes or ETS tables than this VM
  allows runs in a fresh BEAM node started with large enough `+P` and `+e` (the summary's
  `runner` key tells which); its output directory should then be an absolute path.
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, term()}
  def run(opts) do
    case runner_limits(opts) do
      :here ->
        run_here(opts)

      {procs, tables} ->
        name = :"emu_runner_#{System.unique_integer([:positive])}"
        args = ["+P", Integer.to_string(procs), "+e", Integer.to_string(tables)]

        case TartarusTools.Peer.start(name, args: args, apps: [:tartarus, :tartarus_emu]) do
          {:ok, peer, node} ->
            try do
              # The summary the runner writes names the command that asked for it.
              argv = TartarusTools.Provenance.argv()
              :ok = :erpc.call(node, TartarusTools.Provenance, :put_argv, [argv])
              result = :erpc.call(node, __MODULE__, :run_here, [opts], :infinity)

              with {:ok, summary} <- result,
                   do: {:ok, Map.put(summary, :runner, "peer node +P #{procs} +e #{tables}")}
            after
              TartarusTools.Peer.stop(peer)
            end

          error ->
            error
        end
    end
  end

  @doc false
  def run_here(opts) do
    case TartarusEmu.Scenario.run(__MODULE__, opts) do
      {:ok, %{summary: summary}} -> {:ok, Map.put_new(summary, :runner, "this VM")}
      error -> error
    end
  end

  # Processes: per host a supervisor, a server, its overlay process, the plugins'
  # supervisor and the keeper; per agent its process and, while it migrates, its paused
  # copy at the destination.
  defp runner_limits(opts) do
    hosts = Keyword.get(opts, :hosts, default(:hosts))
    agents = Keyword.get(opts, :agents, default(:agents))
    procs = hosts * 6 + agents * 2 + 50_000
    tables = hosts * 2 + 2_000

    virtual? = Keyword.get(opts, :mode, default(:mode)) == :virtual
    topology? = is_binary(Keyword.get(opts, :topology, default(:topology)))

    if virtual? and topology? and
         (procs > :erlang.system_info(:process_limit) or
            tables > :erlang.system_info(:ets_limit)) do
      {max(procs * 2, 1_048_576), max(tables * 2, 16_384)}
    else
      :here
    end
  end

  @impl true
  def setup(opts) do
    mode = opt(opts, :mode)
    strategy = opt(opts, :strategy)
    p = opt(opts, :p)
    seed = opts.seed
    t_start = Clock.machine_time(:millisecond)

    with {:ok, topo} <- topology(opts),
         :ok <- check(strategy in [:random, :conscientious], "strategy", strategy),
         :ok <- check(is_number(p) and p >= 0 and p <= 1, "p", p),
         {:ok, net} <-
           Network.start(topo,
             mode: mode,
             group: opt(opts, :group),
             link: link_opts(opts),
             host_opts: [migration_timeout: opt(opts, :migration_timeout_ms)]
           ) do
      t_net = Clock.machine_time(:millisecond)
      {:ok, log} = Log.start(net, keep_events: opt(opts, :keep_events))
      place_rng = :rand.seed_s(:exsss, {seed, 1, 0})
      agents = opt(opts, :agents)
      {homes, _} = homes(topo, agents, place_rng)
      :ok = create_agents(net, homes, strategy, seed)
      1 = Log.tick(log)
      t_agents = Clock.machine_time(:millisecond)

      {:ok,
       %{
         net: net,
         log: log,
         topo: topo,
         mode: mode,
         strategy: strategy,
         p: p,
         seed: seed,
         agents: agents,
         dyn: Dynamics.new(topo.nodes),
         dyn_rng: :rand.seed_s(:exsss, {seed, 2, 0}),
         visited: MapSet.new(homes, &Network.host(net, &1)),
         trail: [{0, Network.host(net, hd(homes))}],
         steps_run: 0,
         until_covered: opt(opts, :until_covered),
         step_timeout: opt(opts, :step_timeout_ms),
         series: Series.new(),
         covered_at: nil,
         lost: 0,
         wall_us: 0,
         first_us: nil,
         last_us: nil,
         migrations: 0,
         failed: 0,
         topology_name: topology_name(opts),
         network_ms: t_net - t_start,
         agents_ms: t_agents - t_net
       }}
    end
  end

  defp opt(opts, key) do
    case Map.get(opts, key) do
      nil -> default(key)
      v -> v
    end
  end

  defp default(key), do: @schema |> Keyword.fetch!(key) |> Keyword.fetch!(:default)

  defp check(true, _what, _value), do: :ok

  defp check(false, what, value),
    do: {:error, "invalid #{what} for the walk scenario: #{inspect(value)}"}

  defp link_opts(opts) do
    for k <- [:latency_ms, :loss], v = Map.get(opts, k), v != nil, do: {k, v}
  end

  defp topology_name(opts) do
    case Map.get(opts, :topology, default(:topology)) do
      %Topology{kind: kind} -> to_string(kind)
      name -> to_string(name)
    end
  end

  @doc """
  The topology named by `opts` (`:topology`, `:hosts`, `:seed`): see the moduledoc.

      iex> {:ok, topo} = TartarusEmu.Walk.topology(%{topology: "grid", hosts: 12})
      iex> {TartarusEmu.Topology.size(topo), TartarusEmu.Topology.edge_count(topo)}
      {12, 17}
  """
  @spec topology(map()) :: {:ok, Topology.t()} | {:error, String.t()}
  def topology(opts) do
    n = opt(opts, :hosts)

    case opt(opts, :topology) do
      %Topology{} = topo ->
        {:ok, topo}

      _ when not is_integer(n) or n < 1 ->
        {:error, "invalid hosts for the walk scenario: #{inspect(n)}"}

      "grid" ->
        rows = Enum.max(for r <- 1..max(1, trunc(:math.sqrt(n))), rem(n, r) == 0, do: r)
        {:ok, Topology.grid(rows, div(n, rows))}

      "ring" when n >= 3 ->
        {:ok, Topology.ring(n)}

      "line" ->
        {:ok, Topology.line(n)}

      "random" ->
        # Radius at 1.5 times the connectivity threshold sqrt(ln n / (pi n)).
        radius = min(1.5, 1.5 * :math.sqrt(:math.log(max(n, 2)) / (:math.pi() * n)))
        {:ok, Topology.random_geometric(n, radius, Map.get(opts, :seed, 1), connected: true)}

      path when is_binary(path) ->
        if File.exists?(path),
          do: Topology.from_file(path),
          else:
            {:error,
             "invalid topology: expected grid, ring (3+ hosts), line, random or a file, got: #{inspect(path)}"}

      other ->
        {:error, "invalid topology: #{inspect(other)}"}
    end
  rescue
    e in ArgumentError -> {:error, Exception.message(e)}
  end

  defp homes(topo, agents, rng) do
    nodes = List.to_tuple(topo.nodes)

    Enum.map_reduce(1..agents//1, rng, fn _, rng ->
      {i, rng} = :rand.uniform_s(tuple_size(nodes), rng)
      {elem(nodes, i - 1), rng}
    end)
  end

  # Agents are created concurrently, a batch per host; each gets the seed {run seed, i}.
  defp create_agents(net, homes, strategy, seed) do
    coord = self()

    homes
    |> Enum.with_index(1)
    |> Enum.group_by(fn {home, _} -> home end, fn {_, i} -> i end)
    |> Task.async_stream(
      fn {home, ids} ->
        host = Network.host(net, home)

        Enum.each(ids, fn i ->
          {:ok, _} =
            Tartarus.create_mobile_agent(
              host,
              TartarusEmu.Walker,
              %{coord: coord, strategy: strategy, step: 0, trace: i == 1},
              seed: {seed, i}
            )
        end)
      end,
      max_concurrency: System.schedulers_online() * 2,
      timeout: :infinity,
      ordered: false
    )
    |> Stream.run()
  end

  @impl true
  def step(s, k) do
    t0 = Clock.machine_time(:microsecond)

    {events, dyn, dyn_rng} =
      if s.p > 0, do: Dynamics.step(s.dyn, s.p, s.dyn_rng), else: {[], s.dyn, s.dyn_rng}

    Network.apply_dynamics(s.net, events)
    reached = Network.broadcast(s.net, {:emu_step, k})
    deadline = Clock.monotonic_time(:millisecond) + s.step_timeout
    {moved, failed, visited, trail} = await(k, reached, {0, 0, s.visited, s.trail}, deadline)
    t1 = Clock.machine_time(:microsecond)
    wall_us = t1 - t0
    lost = reached - moved - failed
    ^k = Log.tick(s.log) - 1
    totals = Log.totals(s.log, k)
    coverage = MapSet.size(visited) / Topology.size(s.topo)

    series =
      s.series
      |> Series.record(:coverage, k, coverage)
      |> Series.record(:migrations, k, moved)
      |> Series.record(:failed_moves, k, failed)
      |> Series.record(:down_nodes, k, MapSet.size(dyn.down))
      |> Series.record(:bytes, k, totals.bytes)

    %{
      s
      | dyn: dyn,
        dyn_rng: dyn_rng,
        visited: visited,
        trail: trail,
        series: series,
        lost: s.lost + lost,
        wall_us: s.wall_us + wall_us,
        first_us: s.first_us || t0,
        last_us: t1,
        migrations: s.migrations + moved,
        failed: s.failed + failed,
        covered_at: s.covered_at || if(coverage == 1.0, do: k),
        steps_run: k
    }
  end

  # Counts the step's reports: `{moved, failed, visited, trail}`, the trail being the first
  # agent's hops (newest first).
  defp await(_k, reached, {moved, failed, _, _} = acc, _deadline) when moved + failed >= reached,
    do: acc

  defp await(k, reached, {moved, failed, visited, trail} = acc, deadline) do
    timeout = max(deadline - Clock.monotonic_time(:millisecond), 0)

    Clock.receive do
      {:emu_traced, ^k, host} ->
        await(k, reached, {moved, failed, visited, [{k, host} | trail]}, deadline)

      {:emu_traced, _old, _host} ->
        await(k, reached, acc, deadline)

      {:emu_walked, ^k, host, :moved} ->
        await(k, reached, {moved + 1, failed, MapSet.put(visited, host), trail}, deadline)

      {:emu_walked, ^k, _host, :failed} ->
        await(k, reached, {moved, failed + 1, visited, trail}, deadline)

      {:emu_walked, _old, _host, _} ->
        await(k, reached, acc, deadline)
    after
      timeout -> acc
    end
  end

  @impl true
  def done?(s, _k), do: s.until_covered and s.covered_at != nil

  @impl true
  def series(s), do: s.series

  @impl true
  def charts(s) do
    [
      %{
        file: "coverage",
        title: "Walk: coverage, the hosts visited so far",
        subtitle: subtitle(s),
        y_label: "hosts visited",
        y_unit: "fraction of all hosts",
        y_min: 0,
        y_max: 1,
        x_integer: true,
        series: [:coverage]
      },
      %{
        file: "moves",
        title: "Walk: migrations and failed moves per step",
        subtitle: subtitle(s),
        y_label: "moves per step",
        labels: %{migrations: "migrations", failed_moves: "failed moves"},
        series: [:migrations, :failed_moves]
      }
    ]
  end

  @impl true
  def summary(s) do
    :ok = Log.sync(s.log)
    c = Log.counts(s.log)
    params = Energy.params()
    messages = Map.get(c.totals, :departures, 0) + Map.get(c.totals, :clones, 0)
    posted = Map.get(c.totals, :messages, 0)

    energy =
      Energy.total(c.links, params) +
        Energy.cost(%{messages: posted, bytes: Map.get(c.totals, :message_bytes, 0)}, params)

    # The run's real time, pauses between steps (--step-ms) included; the steps' own time is
    # what the rate is over.
    wall_ms = if s.first_us, do: div(s.last_us - s.first_us, 1000), else: 0
    migrations = Map.get(c.totals, :departures, 0)

    %{
      hosts: Topology.size(s.topo),
      links: Topology.edge_count(s.topo),
      agents: s.agents,
      mode: s.mode,
      strategy: s.strategy,
      topology: s.topology_name,
      seed: s.seed,
      p: s.p,
      migrations: migrations,
      migrations_per_s: if(s.wall_us > 0, do: round(migrations * 1_000_000 / s.wall_us), else: 0),
      failed_moves: s.failed,
      messages: messages + posted,
      bytes: Map.get(c.totals, :bytes, 0) + Map.get(c.totals, :message_bytes, 0),
      energy_mj: Float.round(energy * 1.0, 3),
      energy_params: %{per_message_mj: params.per_message, per_byte_mj: params.per_byte},
      wall_ms: wall_ms,
      steps_ms: div(s.wall_us, 1000),
      network_ms: s.network_ms,
      agents_ms: s.agents_ms,
      coverage: MapSet.size(s.visited) / Topology.size(s.topo),
      covered_at_step: s.covered_at,
      lost_reports: s.lost,
      memory_mb: memory_mb(s.net),
      processes: processes(s.net)
    }
  end

  defp memory_mb(net) do
    Enum.sum(for n <- nodes(net), do: rpc(n, :erlang, :memory, [:total], 0)) |> div(1_048_576)
  end

  defp processes(net) do
    Enum.sum(for n <- nodes(net), do: rpc(n, :erlang, :system_info, [:process_count], 0))
  end

  defp nodes(%{mode: :virtual}), do: [node()]
  defp nodes(net), do: Enum.uniq([node() | net.nodes])

  defp rpc(n, m, f, a, default) do
    if n == node(), do: apply(m, f, a), else: :erpc.call(n, m, f, a, 10_000)
  catch
    _, _ -> default
  end

  @impl true
  @doc """
  The parameters and seed of a run, for its figures' subtitles: "grid, 16 hosts, 4 agents,
  random, p 0, seed 1".
  """
  @spec subtitle(map()) :: String.t()
  def subtitle(s) do
    "#{s.topology_name}, #{Topology.size(s.topo)} hosts, #{s.agents} agent#{if s.agents == 1, do: "", else: "s"}, " <>
      "#{s.strategy}, " <>
      "p #{s.p}, seed #{s.seed}"
  end

  @impl true
  def write(s, dir) do
    Log.write_csv!(s.log, dir) ++ figures(s, dir)
  end

  # The topology and the first agent's walk over it (`TartarusEmu.Figures`), with the walk
  # as a CSV, for topologies small enough to draw.
  defp figures(s, dir) do
    if Topology.size(s.topo) <= TartarusEmu.Figures.max_nodes() do
      node_of = Map.new(s.topo.nodes, &{Network.host(s.net, &1), &1})
      path = s.trail |> Enum.reverse() |> Enum.map(fn {k, host} -> {k, node_of[host]} end)
      sub = subtitle(s)

      csv =
        TartarusTools.Report.write_csv!(
          dir,
          "walk_path",
          ["step", "node"],
          Enum.map(path, fn {k, n} -> [k, n] end)
        )

      topo_svg =
        TartarusTools.SVG.write!(
          Path.join(dir, "topology.svg"),
          TartarusEmu.Figures.topology(s.topo, subtitle: sub)
        )

      walk_svg =
        TartarusTools.SVG.write!(
          Path.join(dir, "walk.svg"),
          TartarusEmu.Figures.walk(s.topo, path,
            title: "Walk of agent 1: #{length(path) - 1} hops in #{s.steps_run} steps",
            subtitle: sub
          )
        )

      [csv, topo_svg, walk_svg]
    else
      []
    end
  end

  @impl true
  def teardown(s) do
    Log.stop(s.log)
    Network.stop(s.net)
  end
end
