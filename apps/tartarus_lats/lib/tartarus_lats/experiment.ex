defmodule TartarusLats.Experiment do
  @moduledoc """
  The thesis's comparison (§3.4.2-3.4.5) on one emulated building: the
  centralized cloud design (Scenario 1) and the agent design (Scenario 2)
  run on the same world and answer the same queries. `mix tartarus.lats`
  runs it and writes the report.

  ## One world, both designs

  One `TartarusLats.Deployment` runs the world; its database agents upload
  every new record and vector to the cloud (Scenario 1's traffic, counted
  as `:centralized`). At each query instant the world is paused (between
  two driver steps), the query agents are released together on their start
  nodes (Scenario 2; they contact the cloud from every node where they
  find data of their tag, or once each with `agent_cloud: :per_query`,
  counted as `:agents`), and the same queries are put to the cloud, which answers from
  its mirror (Scenario 1). Agents never read the cloud's mirror.

  ## Queries and ground truth

  Queries come in batches of three, one of each type, released at once, at
  `ceil(queries / 3)` instants after a 120 s warm-up: by default
  (`release: :random`) at world seconds drawn uniformly from the seed,
  about whoever has come into the building, moving or not; with `release:
  :settled`, evenly spread, each batch waiting for a target that is
  **settled** (in its current zone for at least 20 s, or out
  of the building for at least 30 s). Targets and start
  nodes are drawn from the seed: Trace targets rotate over the scripted
  bearers (Head, Janitor, Guard, Professor: the thesis's Fig. 3.9), Where
  is X over all bearers, Where am I over bearers inside the building
  (released on a neighbour of the bearer's zone that is up); Where is X and
  Trace start on a random node that is up.

  The ground truth is the world's (`TartarusLats.World.visited_path/2`). The
  trackers and the zone decision (`TartarusLats.Zone`) see a move a few
  seconds late and an exit is decided by a 15 s handshake timeout, so one
  rule judges settled and moving targets alike: an answer is correct when
  it is true of the bearer at some second of the 15 s before its
  release (`TartarusLats.Judge.correct?/4` spells it out per answer). For a settled target
  that is exact equality with the truth at release. The summary reports
  `correct_settled` and `correct_moving` (shares of the queries whose target
  was, or was not, settled at release), for both designs. Entry/exit times
  of a Trace are reported beside the truth (`trace_time_error_s`: median
  absolute difference of entry times).

  ## Faults

  `kill_nodes: k` kills `k` nodes at world seconds and nodes drawn from the
  seed and restarts each `down_s` seconds later on its data directory (see
  `TartarusLats.Deployment.kill_node/2`): the run goes on, queries are asked
  from nodes that are up, and an answer that needed a dead node names it in
  its `unreachable` list (counted in `answers_partial`).
  """

  @behaviour TartarusEmu.Scenario

  alias TartarusLats.{Building, Cloud, Deployment, World}
  alias TartarusLats.Experiment.{Queries, Summary}

  @schema [
    nodes: [type: :pos_integer, default: 50, doc: "building nodes (at least 10)"],
    bearers: [type: :pos_integer, default: 10, doc: "tag bearers"],
    minutes: [type: :pos_integer, default: 20, doc: "world minutes"],
    queries: [type: :pos_integer, default: 30, doc: "queries"],
    seed: [type: :integer, default: 1, doc: "seed of the world and of the queries"],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    group: [type: :pos_integer, default: 10, doc: "building nodes per BEAM node in peer mode"],
    out: [type: :any, doc: "output directory (default `results/lats-<UTC timestamp>`), or false"],
    quiet: [type: :boolean, default: false, doc: "no progress line"],
    release: [
      type: {:in, [:random, :settled]},
      default: :random,
      doc:
        "when queries are released: at random world seconds, whatever the target is doing (default), or only when the target is settled"
    ],
    noise_db: [
      type: {:range, 0, 40},
      default: 4.0,
      doc: "standard deviation of the radio's Gaussian noise (dB)"
    ],
    kill_nodes: [
      type: :non_neg_integer,
      default: 0,
      doc:
        "nodes killed during the run (at world seconds and nodes drawn from the seed, after the warm-up), each restarted `down_s` later on its data directory"
    ],
    down_s: [type: :pos_integer, default: 60, doc: "world seconds a killed node stays down"],
    agent_cloud: [
      type: {:in, [:per_node, :per_query]},
      default: :per_node,
      doc:
        "when query agents contact the cloud: from every node where they find data of the tag (the thesis's scenario 2), or once per query"
    ],
    repair: [
      type: :boolean,
      default: false,
      doc:
        "Where is X and Trace agents bridge a broken chain of motion vectors (`TartarusLats.Query.WhereIs`, `TartarusLats.Query.Trace`, `:repair`)"
    ],
    record: [
      type: :any,
      doc:
        "a file to record every node's HM-10 serial output to (`TartarusLats.HM10.Recording`; gzip if it ends in `.gz`)"
    ],
    replay: [
      type: :any,
      doc:
        "a recording whose serial output the nodes hear instead of the simulated radio; the world (the ground truth) still moves by the seed, so a recording made with the same seed and options replays the same run"
    ],
    dashboard: [
      type: :non_neg_integer,
      doc:
        "serve the web dashboard on this port while the run goes, with the LATS panel (`TartarusLats.DashboardPanel`)"
    ],
    step_ms: [type: :non_neg_integer, default: 0, doc: "pause after each world second (to watch)"]
  ]

  @doc "The options of `run/1` (a `Tartarus.Options` schema; `mix tartarus.lats` reads its defaults here)."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Runs the experiment as a `TartarusEmu.Scenario` (one step per world
  second) and writes its report (`TartarusLats.Report`). Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, %{summary:, series:, out:, files:}}` (see
  `TartarusEmu.Scenario.run/2`; the summary keys are listed in `mix help
  tartarus.lats`) or `{:error, message}` for bad options.
  """
  @spec run(keyword()) :: {:ok, TartarusEmu.Scenario.result()} | {:error, term()}
  def run(opts \\ []) do
    with {:ok, opts} <- validate(opts),
         {:ok, opts} <- load_replay(opts) do
      {runner, rest} = Keyword.split(opts, [:seed, :out, :quiet, :dashboard, :step_ms])
      TartarusEmu.Scenario.run(__MODULE__, runner ++ [steps: opts[:minutes] * 60] ++ rest)
    end
  end

  defp load_replay(opts) do
    case opts[:replay] do
      nil ->
        {:ok, opts}

      path when is_binary(path) ->
        with {:ok, recording} <- TartarusLats.HM10.Recording.read(path),
             :ok <- known_nodes(recording, building(opts[:nodes]), path),
             do: {:ok, Keyword.put(opts, :replay, recording)}

      other ->
        {:error,
         "invalid options given to TartarusLats.Experiment.run/1 for key :replay: expected a file path, got: #{inspect(other)}"}
    end
  end

  defp known_nodes(recording, building, path) do
    known = MapSet.new(Building.nodes(building), &to_string/1)

    case for({_t, nodes} <- recording, n <- Map.keys(nodes), n not in known, uniq: true, do: n) do
      [] ->
        :ok

      unknown ->
        {:error,
         "#{path} names nodes a building of #{length(Building.nodes(building))} nodes does not have: #{Enum.join(Enum.sort(unknown), ", ")}"}
    end
  end

  defp open_recording(nil), do: nil

  defp open_recording(path) do
    File.mkdir_p!(Path.dirname(path))
    modes = if String.ends_with?(path, ".gz"), do: [:write, :compressed], else: [:write]
    io = File.open!(path, [:binary | modes])
    IO.binwrite(io, TartarusLats.HM10.Recording.header())
    io
  end

  @doc """
  Checks `run/1`'s options against `schema/0` (and `:nodes` >= 10); returns them with the
  defaults filled in, or `{:error, message}` naming the key, what was expected and what
  arrived.

      iex> {:ok, opts} = TartarusLats.Experiment.validate(nodes: 20)
      iex> {opts[:nodes], opts[:minutes], opts[:mode]}
      {20, 20, :virtual}
      iex> TartarusLats.Experiment.validate(nodes: 5)
      {:error, "invalid options given to TartarusLats.Experiment.run/1 for key :nodes: expected an integer >= 10, got: 5"}
  """
  @spec validate(keyword()) :: {:ok, keyword()} | {:error, String.t()}
  def validate(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusLats.Experiment.run/1"),
         :ok <- check_nodes(opts[:nodes]) do
      {:ok, opts}
    end
  end

  defp check_nodes(n) when n >= 10, do: :ok

  defp check_nodes(n),
    do:
      {:error,
       "invalid options given to TartarusLats.Experiment.run/1 for key :nodes: expected an integer >= 10, got: #{n}"}

  # -- the scenario ------------------------------------------------------------------

  @impl TartarusEmu.Scenario
  def name, do: "lats"

  @impl TartarusEmu.Scenario
  def title, do: "LATS (thesis ch. 3): agents vs cloud"

  @impl TartarusEmu.Scenario
  def setup(opts) do
    building = building(opts.nodes)
    world = world(building, opts.bearers, opts.noise_db)
    duration = opts.steps

    # Killed nodes come back on their data directory (their log and vectors survive).
    data_dir =
      if opts.kill_nodes > 0,
        do: Path.join(System.tmp_dir!(), "lats-#{System.unique_integer([:positive])}")

    dep =
      Deployment.start(
        seed: opts.seed,
        world: world,
        mode: opts.mode,
        group: opts.group,
        data_dir: data_dir,
        record: open_recording(opts[:record]),
        replay: opts[:replay]
      )

    {:ok,
     %{
       dep: dep,
       rng: :rand.seed_s(:exsss, opts.seed * 7919 + 11),
       schedule: Queries.schedule(opts.queries, duration, opts.release, opts.seed),
       faults: faults(opts.kill_nodes, opts.down_s, building, duration, opts.seed),
       kills: 0,
       data_dir: data_dir,
       release: opts.release,
       janitor: if(:janitor in World.names(world), do: World.tag(world, :janitor)),
       pending: [],
       results: [],
       rssi: [],
       k: 0,
       series: TartarusTools.Series.new(),
       meta: %{
         # What was built: --nodes is rounded to whole rows (see building/1).
         nodes: length(Building.nodes(building)),
         bearers: opts.bearers,
         minutes: opts.minutes,
         mode: to_string(opts.mode),
         agent_cloud: to_string(opts.agent_cloud),
         release: to_string(opts.release),
         kill_nodes: opts.kill_nodes,
         down_s: opts.down_s,
         noise_db: opts.noise_db,
         repair: opts.repair
       }
     }}
  end

  @impl TartarusEmu.Scenario
  def step(state, _step) do
    dep = Deployment.step(state.dep)
    state = %{state | dep: dep} |> record_rssi() |> apply_faults()
    due = Map.get(state.schedule, dep.time, [])
    state = fire(%{state | pending: state.pending ++ due})
    record_series(state)
  end

  defp record_series(%{dep: %{time: t}} = state) when rem(t, 10) == 0 do
    series =
      state.series
      |> TartarusTools.Series.record(:cloud_uploads_centralized, t, state.dep.uploads)
      |> TartarusTools.Series.record(:queries_answered, t, length(state.results))

    %{state | series: series}
  end

  defp record_series(state), do: state

  @impl TartarusEmu.Scenario
  def series(state), do: state.series

  @impl TartarusEmu.Scenario
  def summary(state) do
    meta =
      Map.merge(state.meta, %{
        node_kills: state.kills,
        nodes_down_at_end: MapSet.size(state.dep.down)
      })

    Summary.summarize(Enum.reverse(state.results), Cloud.stats(state.dep.cloud), state.dep, meta)
  end

  @impl TartarusEmu.Scenario
  def comparisons(state), do: TartarusLats.Report.comparisons(summary(state))

  @impl TartarusEmu.Scenario
  def network(state), do: state.dep.net

  @impl TartarusEmu.Scenario
  def panels(state) do
    world = state.dep.world
    bearers = Map.new(World.names(world), &{World.tag(world, &1), &1})
    [{TartarusLats.DashboardPanel, %{net: state.dep.net, bearers: bearers}}]
  end

  @impl TartarusEmu.Scenario
  def write(state, dir) do
    TartarusLats.Report.write!(dir, %{
      summary: summary(state),
      queries: Enum.reverse(state.results),
      cloud_log: Cloud.stats(state.dep.cloud).log,
      rssi: Enum.reverse(state.rssi),
      world: state.dep.world
    })
  end

  @impl TartarusEmu.Scenario
  def teardown(state) do
    if state.dep.record, do: File.close(state.dep.record)
    Deployment.stop(state.dep)
    if state.data_dir, do: File.rm_rf(state.data_dir)
    :ok
  end

  @doc """
  The building for `nodes` nodes: the thesis's 50 (2 floors of 5 x 5) by
  default; otherwise 2 floors of `rows x 5` (rounded to a multiple of 10, at
  least 10).
  """
  @spec building(pos_integer()) :: Building.t()
  def building(50), do: Building.new()

  def building(nodes) when is_integer(nodes) and nodes > 0 do
    Building.new(floors: 2, cols: 5, rows: max(1, div(nodes + 5, 10)))
  end

  defp world(building, bearers, noise_db) do
    scripts = World.default_scripts(building)
    radio = TartarusLats.Radio.new(noise_sigma: noise_db)

    if bearers >= length(scripts) do
      World.new(
        building: building,
        radio: radio,
        walkers: bearers - length(scripts),
        scripts: scripts
      )
    else
      World.new(
        building: building,
        radio: radio,
        walkers: 0,
        scripts: Enum.take(scripts, bearers)
      )
    end
  end

  # -- node kills ------------------------------------------------------------------

  # %{second => [{:kill | :revive, node}]}: k kills at seconds drawn after the warm-up (a
  # node already down at its second is not killed again), each revived down_s later.
  defp faults(0, _down, _building, _duration, _seed), do: %{}

  defp faults(k, down, building, duration, seed) do
    nodes = Building.nodes(building)
    rng = :rand.seed_s(:exsss, {seed, 4409, 23})
    span = max(duration - Queries.warmup() - down, 1)

    {acc, _} =
      Enum.reduce(1..k, {%{}, rng}, fn _, {acc, rng} ->
        {x, rng} = :rand.uniform_s(span, rng)
        {i, rng} = :rand.uniform_s(length(nodes), rng)
        node = Enum.at(nodes, i - 1)
        t = Queries.warmup() + x

        acc =
          acc
          |> Map.update(t, [{:kill, node}], &(&1 ++ [{:kill, node}]))
          |> Map.update(t + down, [{:revive, node}], &(&1 ++ [{:revive, node}]))

        {acc, rng}
      end)

    acc
  end

  defp apply_faults(%{dep: dep} = state) do
    Enum.reduce(Map.get(state.faults, dep.time, []), state, fn
      {:kill, node}, state ->
        if MapSet.member?(state.dep.down, node),
          do: state,
          else: %{state | dep: Deployment.kill_node(state.dep, node), kills: state.kills + 1}

      {:revive, node}, state ->
        if MapSet.member?(state.dep.down, node),
          do: %{state | dep: Deployment.revive_node(state.dep, node)},
          else: state
    end)
  end

  # -- firing --------------------------------------------------------------------

  defp fire(%{pending: []} = acc), do: acc

  defp fire(acc) do
    world = acc.dep.world

    {batch, waiting, rng, k} =
      Enum.reduce(acc.pending, {[], [], acc.rng, acc.k}, fn type, {batch, waiting, rng, k} ->
        case Queries.pick(type, world, acc.dep, rng, k, acc.release) do
          {nil, rng} -> {batch, waiting ++ [type], rng, k}
          {q, rng} -> {batch ++ [q], waiting, rng, k + 1}
        end
      end)

    results =
      Queries.ask(
        batch,
        acc.dep,
        String.to_existing_atom(acc.meta.agent_cloud),
        acc.meta.repair
      )

    %{acc | pending: waiting, rng: rng, k: k, results: Enum.reverse(results) ++ acc.results}
  end

  # -- RSSI (Fig. 3.6/3.7) ----------------------------------------------------------

  @rssi_seconds 400

  defp record_rssi(%{janitor: nil} = acc), do: acc
  defp record_rssi(%{dep: %{time: t}} = acc) when t > @rssi_seconds, do: acc

  defp record_rssi(%{janitor: tag} = acc) do
    raw = acc.dep.readings

    row =
      Map.new(acc.dep.hosts, fn {node, host} ->
        # A node that is down has no filtered value.
        filtered =
          case Tartarus.store_get(host, {:lats, :filtered}, %{}) do
            %{} = values -> Map.get(values, tag)
            _ -> nil
          end

        r = get_in(raw, [node, tag])
        {node, {if(is_number(r), do: r, else: nil), filtered}}
      end)

    %{acc | rssi: [{acc.dep.time, row} | acc.rssi]}
  end
end
