defmodule Mix.Tasks.Tartarus.Lats do
  @shortdoc "LATS: agent queries vs the cloud baseline on an emulated building (thesis ch. 3)"
  @moduledoc """
  Runs the LATS comparison of the thesis (§3.4): the centralized cloud design
  and the mobile-agent design on the same emulated building, world and
  queries (see `TartarusLats.Experiment`).

      mix tartarus.lats [--nodes 50] [--bearers 10] [--minutes 20] [--queries 30]
                        [--mode virtual|peer] [--group 10] [--seed 1] [--out DIR] [--json]
                        [--record FILE | --replay FILE] [--agent-cloud per_node|per_query]
                        [--release random|settled] [--noise-db 4.0]
                        [--kill-nodes 0] [--down-s 60] [--repair] [--dashboard PORT] [--step-ms MS]

  ## Real recordings (`--replay-log`)

      mix tartarus.lats --replay-log PATH --devices FILE [--calibration FILE]
                        [--fingerprints DIR] [--floor-plan FILE] [--seed 1] [--seeds 3]
                        [--queries 10] [--window 4] [--no-repair] [--mode virtual|peer]
                        [--group 6] [--out DIR] [--json]

  replays real multi-receiver RSSI logs into LATS instead of the emulated building
  (`TartarusLats.Replay.Experiment`; the rules are in docs/lats.md, "LATS on real BLE
  recordings"). `--replay-log` is a log file, a comma-separated list of them, or a
  directory (every `.mbd` and `.csv` file in it), one track each; the format is
  `time, receiver, beacon, rssi[, x, y]` (`TartarusLats.Replay.Log`; the tetam `.mbd` files
  as they are). `--devices` gives the receivers' positions (tetam `.dev` or CSV `receiver,
  x, y, z[, name]`); one LATS node per receiver, neighbours by the Delaunay graph (or
  `--floor-plan FILE`). `--calibration` is a file written by `mix tartarus.lats.calibrate`;
  `--fingerprints DIR` (reference recordings) enables the fingerprinting baseline (without
  it the baseline is absent from every output). A track that cannot be judged (no valid
  reading, none from a receiver of the devices file, no true position, nothing after the
  5 s warm-up) ends the task with one line saying why and a non-zero exit; bad lines (with
  their numbers and why), a last line without a newline (not read: it may be cut short) and
  readings of receivers the devices file does not name are printed per track and listed in
  `summary.json` (`bad_lines`, `log_unterminated_line`, `unknown_receivers`). Each
  track runs with seeds `--seed` .. `--seed + --seeds - 1` (the seed draws the query
  instants and start nodes) through `TartarusEmu.Sweep`. The Where is X and Trace agents bridge
  a broken chain of motion vectors (`TartarusLats.Query.WhereIs`,
  `TartarusLats.Query.Trace`, `:repair`) unless `--no-repair` is given. Writes into `--out DIR` (default
  `results/lats-replay-<time>`): per track `<track>_seconds.csv`, `<track>_queries.csv`,
  `<track>.svg` (`TartarusLats.Replay.Report`), `floor_plan.txt`, the sweep's `runs.csv`,
  box plots, `summary.json` and `summary.md` (per track and design, `lats`, `thesis` (the
  thesis's own rule without the zone decision, an arm on a deployment of its own),
  `strongest` and `knn`: exact and adjacent
  rates, zone changes against the true ones, Where is X correct, Trace edit distance,
  cloud connections; `pass`: the pre-registered criterion; per track `holders`: the most
  nodes that held the tag at once and the holder's jumps to non-neighbours). With `--json`
  the summary is the last line.

  `--dashboard PORT` serves the web dashboard (127.0.0.1) while the run goes, with a LATS
  panel (where each tag bearer is heard, the query agents out; `TartarusLats.DashboardPanel`);
  `--step-ms MS` pauses after each world second so that a person can watch.

  The defaults are those of `TartarusLats.Experiment.schema/0`; `--nodes` is
  at least 10 and is rounded to whole rows of 5 on 2 floors (`--nodes 15` builds 20; the
  line printed and the summary's `nodes` say what was built). `--help` prints this text.

  The experiment is a `TartarusEmu.Scenario` (one step per world second, a
  progress line on standard error) and writes into `--out DIR` (default
  `results/lats-<UTC timestamp>`, relative to the current directory):

    * `queries.csv` - every query: type, person, start node, world time, settled, answer,
      truth, correct (agents, centralized), hops, ms, route;
    * `cloud_connections.csv`, `cloud_connections.svg` - cumulative connections to
      the cloud over world time: centralized (every upload; the CSV also per person),
      agents (contacts of every query, and of the Trace queries about each scripted
      bearer): the thesis's Fig. 3.9; `cloud_connections_agents.svg` - the agents'
      curves alone, on a scale of their own;
    * `rssi.csv`, `rssi.svg` - raw and filtered RSSI of the Janitor's tag at two
      zones, 40 s either side of the Janitor's first hand-over into a zone where it
      then stays 20 s or more, with the thresholds (regions labelled) and the true
      hand-over (Figs. 3.6-3.7);
    * `hops.svg`, `latency.svg` - box plots of query hops and latency per type;
    * `series.csv`, `cloud_uploads_centralized.{csv,svg}`,
      `queries_answered.{csv,svg}` - the scenario's series (every 10 world s);
    * `summary.json`, `summary.md` - the keys below, and ours vs the thesis.

  `--record FILE` writes every node's HM-10 serial output of every second into FILE
  (gzip-compressed if it ends in `.gz`; the format is in
  `TartarusLats.HM10.Recording`). `--replay FILE` feeds such a recording to the nodes'
  receivers instead of the simulated radio: each node's text goes through the HM-10 parser
  (`TartarusLats.HM10`) as if it came from its UART. The world still moves by the seed (it
  is the ground truth the answers are judged against), so a recording replayed with the seed
  and options it was made with reproduces the run; a capture from real hardware replays
  too, but its answers are judged against a world that was not there.

  `--release` says when queries are released: `random` (default: batches of three at world
  seconds drawn from the seed after a 120 s warm-up, about whoever has come into the
  building, moving or not) or `settled` (only about a target settled in its zone for 20 s or
  out for 30 s). `--noise-db` is the radio's Gaussian noise (default 4 dB). One definition of
  a correct answer serves both (`TartarusLats.Judge.correct?/4`): the answer must be
  true of the target at some second of the 15 s before the release (the trackers' lag);
  the summary splits it into `correct_settled` and `correct_moving` (shares of the queries
  whose target was, or was not, settled at release).

  `--kill-nodes K` kills K nodes during the run (world seconds and nodes drawn from the
  seed, after the warm-up) and restarts each `--down-s` world seconds later on its data
  directory (its log and motion vectors survive; its tracker starts afresh). The run goes
  on: the driver leaves dead nodes out, queries are asked from nodes that are up, and an
  answer that needed a dead node names it in `unreachable` (counted in `answers_partial`;
  such an answer is never `complete`). Kills happen between world seconds, while no query
  agent is walking.

  `--repair` lets the Where is X and Trace agents bridge a broken chain of motion vectors:
  at a dead end or a break (an entry from outside or an exit where there is no door, a
  vector with no matching one) they ask the nodes within two rings of it for the tag's
  stays in that time window and follow the chain on from there
  (`TartarusLats.Query.WhereIs`, `TartarusLats.Query.Trace`; off by default). Every
  Trace answer names the breaks it met (`breaks`); one with a break not bridged from a
  neighbour is not complete.

  `--agent-cloud` says when query agents contact the cloud: `per_node` (default, the
  thesis's scenario 2: from every node where they find data of the tag) or `per_query`
  (once, from where the answer was found). The summary reports what both rules cost for the
  same queries (`cloud_connections_agents_per_node`, `_per_query`);
  `cloud_connections_agents` and the plots count the contacts made under the rule applied.

  Summary keys: `queries, correct, correct_centralized, queries_settled, queries_moving,
  correct_settled, correct_moving, correct_settled_centralized, correct_moving_centralized,
  release, noise_db, kill_nodes, down_s, node_kills, nodes_down_at_end, answers_partial,
  cloud_connections_centralized, cloud_connections_agents, cloud_connection_ratio,
  cloud_connections_agents_per_node, cloud_connections_agents_per_query, agent_cloud,
  answers_stale, answers_incomplete, answers_complete_wrong, breaks, breaks_bridged,
  breaks_bridged_far, cloud_bytes_centralized, cloud_bytes_agents, median_query_hops, max_query_hops,
  median_query_ms, trace_time_error_s, by_type (per query type: queries, correct,
  complete_wrong, median_hops), nodes, bearers, minutes, seed, mode,
  repair, world_seconds, input, replay_records, replay_bad_records, replay_garbage_bytes` and the
  runner's `scenario, steps, setup_ms, run_ms`. Medians are
  nearest-rank (`TartarusTools.Stats.median/1`). With `--json` the last line printed is the summary as one
  JSON object.
  """
  use TartarusTools.CLI

  alias TartarusLats.Experiment

  @switches [
    nodes: :integer,
    bearers: :integer,
    minutes: :integer,
    queries: :integer,
    mode: :string,
    group: :integer,
    seed: :integer,
    out: :string,
    record: :string,
    replay: :string,
    agent_cloud: :string,
    release: :string,
    noise_db: :float,
    kill_nodes: :integer,
    down_s: :integer,
    dashboard: :integer,
    step_ms: :integer,
    replay_log: :string,
    devices: :string,
    calibration: :string,
    fingerprints: :string,
    floor_plan: :string,
    seeds: :integer,
    window: :integer,
    repair: :boolean,
    json: :boolean,
    help: :boolean
  ]

  @impl true
  def run(argv) do
    opts = TartarusTools.CLI.parse!(argv, @switches, "tartarus.lats")

    cond do
      opts[:help] -> Mix.shell().info(@moduledoc)
      opts[:replay_log] -> run_replay(opts)
      true -> run_experiment(opts)
    end
  end

  @replay_flags [:replay_log, :devices, :calibration, :fingerprints, :floor_plan] ++
                  [:seed, :seeds, :queries, :window, :repair, :mode, :group, :out, :json]

  defp run_replay(opts) do
    task = "tartarus.lats"

    case Keyword.keys(opts) -- @replay_flags do
      [] ->
        :ok

      other ->
        TartarusTools.CLI.error!(task, "--#{dash(hd(other))} does not go with --replay-log")
    end

    unless opts[:devices], do: TartarusTools.CLI.error!(task, "--replay-log needs --devices FILE")
    TartarusTools.CLI.positive!(opts, [:seeds, :queries, :window, :group], task)

    for key <- [:devices, :calibration, :floor_plan],
        path = opts[key],
        not File.regular?(path),
        do: TartarusTools.CLI.error!(task, "--#{dash(key)}: file not found: #{path}")

    if opts[:fingerprints] && not File.dir?(opts[:fingerprints]),
      do:
        TartarusTools.CLI.error!(
          task,
          "--fingerprints: directory not found: #{opts[:fingerprints]}"
        )

    logs = replay_logs(opts[:replay_log], task)
    mode = TartarusTools.CLI.choice!(opts[:mode], [:virtual, :peer], :mode, task, :virtual)
    json? = Keyword.get(opts, :json, false)
    Mix.Task.run("app.start")

    exp =
      opts
      |> Keyword.take([
        :devices,
        :calibration,
        :fingerprints,
        :floor_plan,
        :seed,
        :seeds,
        :queries,
        :window,
        :repair,
        :group,
        :out
      ])
      |> Keyword.merge(logs: logs, mode: mode, quiet: json?)

    case TartarusLats.Replay.Experiment.run(exp) do
      {:ok, %{summary: summary, out: dir}} ->
        if json? do
          TartarusTools.CLI.report(summary, json: true)
        else
          for {name, t} <- Enum.sort(summary.tracks) do
            for d <- [:lats, :thesis, :strongest, :knn], x = t[d] do
              Mix.shell().info(
                "#{name} #{d}: exact #{show(x.exact)}, adjacent #{show(x.adjacent)}, " <>
                  "changes #{x.changes} (true #{x.true_changes}), Where is X #{x.where_is_correct}/#{x.where_is}, " <>
                  "Trace edit #{show(x.trace_edit_mean)}, cloud #{x.cloud_connections_per_run}"
              )
            end

            h = t.holders

            Mix.shell().info(
              "#{name} holders: at most #{h.holders_at_once} at once (#{h.seconds_with_two_holders} s with two or more), " <>
                "#{h.non_neighbour_jumps} of #{h.changes} holder changes to a non-neighbour " <>
                "(#{h.non_neighbour_jumps_without_release} without a release between)"
            )

            for line <- TartarusLats.Replay.Experiment.input_lines(t),
                do: Mix.shell().info("#{name} input: #{line}")
          end

          Mix.shell().info("pass (pre-registered criterion): #{summary.pass}\nwritten to #{dir}")
        end

      {:error, message} ->
        TartarusTools.CLI.error!(task, message)
    end
  end

  defp replay_logs(path, task) do
    logs =
      cond do
        File.dir?(path) ->
          path
          |> File.ls!()
          |> Enum.filter(&(Path.extname(&1) in [".mbd", ".csv"]))
          |> Enum.sort()
          |> Enum.map(&Path.join(path, &1))

        true ->
          String.split(path, ",", trim: true)
      end

    missing = Enum.reject(logs, &File.regular?/1)

    cond do
      logs == [] ->
        TartarusTools.CLI.error!(task, "--replay-log: no .mbd or .csv files in #{path}")

      missing != [] ->
        TartarusTools.CLI.error!(task, "--replay-log: file not found: #{hd(missing)}")

      true ->
        logs
    end
  end

  defp dash(key), do: key |> Atom.to_string() |> String.replace("_", "-")

  defp run_experiment(opts) do
    # Flags that name one of a few values: turned into the experiment's atoms here.
    choices =
      for {key, values} <- [
            mode: [:virtual, :peer],
            agent_cloud: [:per_node, :per_query],
            release: [:random, :settled]
          ],
          value = TartarusTools.CLI.choice!(opts[key], values, key, "tartarus.lats", nil),
          value != nil,
          do: {key, value}

    json? = Keyword.get(opts, :json, false)

    exp_opts =
      opts
      |> Keyword.drop([:json, :help, :mode, :agent_cloud, :release])
      |> Keyword.merge(choices)
      |> Keyword.put(:quiet, json?)

    shown =
      case Experiment.validate(exp_opts) do
        {:ok, shown} -> shown
        {:error, message} -> TartarusTools.CLI.error!("tartarus.lats", message)
      end

    if shown[:record] && shown[:replay],
      do: Mix.raise("mix tartarus.lats: --record and --replay cannot be given together")

    Mix.Task.run("app.start")

    built = length(TartarusLats.Building.nodes(Experiment.building(shown[:nodes])))

    rounded =
      if built != shown[:nodes],
        do: " (--nodes #{shown[:nodes]} rounded to whole rows: 2 floors x rows of 5)",
        else: ""

    unless json?,
      do:
        Mix.shell().info(
          "LATS: #{built} nodes#{rounded}, seed #{shown[:seed]}, #{shown[:mode]} hosts..."
        )

    case Experiment.run(exp_opts) do
      {:ok, %{summary: summary, out: dir}} ->
        if json? do
          TartarusTools.CLI.report(summary, json: true)
        else
          Mix.shell().info("""
          queries: #{show(summary.queries)}, correct: #{show(summary.correct)} (centralized: #{show(summary.correct_centralized)})
          correct, settled / moving targets: #{show(summary.correct_settled)} / #{show(summary.correct_moving)} (#{show(summary.release)} release, #{show(summary.noise_db)} dB noise)
          cloud connections: centralized #{show(summary.cloud_connections_centralized)}, agents #{show(summary.cloud_connections_agents)} (ratio #{show(summary.cloud_connection_ratio)})
          cloud bytes: centralized #{show(summary.cloud_bytes_centralized)}, agents #{show(summary.cloud_bytes_agents)}
          median query hops #{show(summary.median_query_hops)}, median latency #{show(summary.median_query_ms)} ms
          written to #{dir}\
          """)
        end

      {:error, message} ->
        TartarusTools.CLI.error!("tartarus.lats", message)
    end
  end

  # A share with no queries behind it (no target moving at release, say) is nil.
  defp show(nil), do: "- (no such queries)"
  defp show(x), do: TartarusTools.CLI.show(x)
end
