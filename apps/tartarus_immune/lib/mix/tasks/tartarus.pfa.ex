defmodule Mix.Tasks.Tartarus.Pfa do
  @shortdoc "Robots learn which path-following algorithm suits which sub-path (thesis §6.5.11)"
  @moduledoc """
  Runs the path-following experiment of thesis §6.5.11 (see
  `TartarusImmune.PathFollowing.Experiment`): two robots drive Path-1 and Path-2 of the
  arena at once; at each sub-path a robot's host emits a danger signal carrying the
  sub-path's features, iPkts carrying PFA-to-sub-path mappings are drawn to it, the host's
  localized idiotypic network picks one, the robot runs that PFA and its measured cost
  (time, staying on the line) feeds back; each robot receives one new random PFA per lap;
  the mappings travel between the robots as agents (fresh clones, by default).

      mix tartarus.pfa [--laps 12] [--seeds 10] [--seed 1] [--out DIR] [--json]
                       [--explore untried_first|activation|P] [--n-min 1]
                       [--sharing clones|roam|none] [--stream once|lifelong]
                       [--challenge tried|activation] [--stuck-after 6] [--lost-penalty 5]
                       [--no-danger] [--no-exhaustive] [--quiet]

  `--explore` is when a robot tries a PFA it has not measured on a sub-path's type:
  `untried_first` (default: at its first chance, so every PFA the stream brings is run
  once on every type, as the thesis's robots executed the PFAs they received),
  `activation` (when the new iPkt's activation τ_init is at least the largest activation
  of the measured candidates after their LIN round: exploration fades, but an incumbent
  that keeps failing is never challenged) or a probability P (a coin per sub-path).
  `--n-min` is how many measures a PFA needs on a type before suppression can kill it.
  `--sharing` is how mappings travel between the robots: `clones` (default: fresh clones
  go to the other robot, every other iPkt stays in its robot's repertoire), `roam` (every
  iPkt not held by a pending problem moves on), `none`. `--stream` is the input stream:
  `once` (default: each PFA once per robot, so nothing new after the eighth lap) or
  `lifelong` (then, each lap, a PFA whose mapping of some type has died out at the robot
  is injected again for those types; `--challenge tried` makes it enter at τ_max so it
  runs once, `activation` at τ_init). `--stuck-after S` (default 6) is how long a robot
  may make no progress before the experimenter nudges it 10 cm on, and `--lost-penalty S`
  (default 5) the seconds charged for that and for each put-back on the line. The trials
  are a `TartarusEmu.Sweep` (a trial a seed), a line per finished trial on standard error
  unless `--quiet`.

  Output (in `--out DIR`, default `results/pfa-<UTC timestamp>`): `lap_times.csv` (trial,
  seed, path, lap, seconds), `lap_times_trial1.svg` (one trial, Fig. 6.13a),
  `lap_times_mean.svg` (the mean over trials, Fig. 6.13b), `choices.csv` (every sub-path
  crossed: the PFA used and its measure, with put-backs, nudges and their penalty), `best_pfa.csv` (the best PFA per sub-path type
  beside Table 6.5 and the exhaustive search), `summary.json`, `summary.md`, and the
  sweep's `runs.csv` (a row per trial: its seed, the mean of its last 3 laps, its plateau
  lap and how often its robot was lost, per path) with a box plot per such metric.

  Summary keys: `trials, laps, lap_times` (`trial1`, `mean` and `per_trial`, each per
  path), `plateau_lap` (per path: on the mean curve, the first lap L such that every lap
  from L to the last is within 10% of the mean of the last 3 laps), `plateau_time` (the
  mean lap time from there), `plateau_lap_5pct` (the same within 5%),
  `plateau_lap_per_trial`, `explore`, `sharing`, `n_min`, `stream`, `stuck_after`,
  `lost_per_trial`, `failures` (per path: put-backs, nudges, penalty seconds, share of the
  time), `best_pfa` (per sub-path type: the
  most frequent network choice over the trials) and `best_pfa_counts`,
  `best_pfa_table6_5`, `exhaustive_best` and `exhaustive_costs` (every PFA alone over
  every sub-path instance of the first seed), `matches_exhaustive`, `matches_table6_5`,
  `counters` (iPkts injected, born, died, migrations, ...), `sim_seconds`,
  `wall_seconds`, `sim_speed_x` (simulated seconds per wall second, immune network
  included), `sweep` (per metric of `runs.csv`: n, mean, sd, median, quartiles over the
  trials). With `--json`
  the last line printed is the summary as one JSON object.

  `--help` prints this text.

  `--seeds N` (or its old name `--trials N`) is the number of repetitions, on seeds
  `--seed`, `--seed` + 1, ...: the name `mix tartarus.select` uses for the same thing.
  """
  use TartarusTools.CLI

  alias TartarusImmune.PathFollowing.Experiment

  @task "tartarus.pfa"

  @impl true
  def run(argv) do
    schema =
      Experiment.schema()
      |> Keyword.drop([:pfas, :params])
      |> Keyword.update!(:out, &Keyword.merge(&1, type: :string, default: nil))
      |> Keyword.update!(:sharing, &Keyword.merge(&1, type: :string, default: "clones"))
      |> Keyword.update!(:explore, &Keyword.merge(&1, type: :string, default: "untried_first"))
      |> Keyword.update!(:stream, &Keyword.merge(&1, type: :string, default: "once"))
      |> Keyword.update!(:challenge, &Keyword.merge(&1, type: :string, default: "tried"))
      |> Keyword.put(:json, type: :boolean, default: false, doc: "print the summary as JSON")

    opts = TartarusTools.CLI.options!(argv, schema, @task, synonyms: [seeds: :trials])
    json? = opts[:json]

    sharing =
      TartarusTools.CLI.choice!(opts[:sharing], [:clones, :roam, :none], :sharing, @task, :clones)

    exp_opts =
      opts
      |> Keyword.drop([:json])
      |> Keyword.put(:sharing, %{clones: :clones, roam: true, none: false}[sharing])
      |> Keyword.put(:explore, explore!(opts[:explore]))
      |> Keyword.put(
        :stream,
        TartarusTools.CLI.choice!(opts[:stream], [:once, :lifelong], :stream, @task, :once)
      )
      |> Keyword.put(
        :challenge,
        TartarusTools.CLI.choice!(
          opts[:challenge],
          [:tried, :activation],
          :challenge,
          @task,
          :tried
        )
      )

    exp_opts = if opts[:out], do: exp_opts, else: Keyword.delete(exp_opts, :out)
    Mix.Task.run("app.start")

    case Experiment.run(exp_opts) do
      {:ok, %{summary: s, out: dir}} ->
        TartarusTools.CLI.report(s, [json: json?], fn s -> text(s, dir) end)

      {:error, message} ->
        TartarusTools.CLI.error!(@task, message)
    end
  end

  defp explore!(value) do
    case {value, Float.parse(value)} do
      {"activation", _} ->
        :activation

      {"untried_first", _} ->
        :untried_first

      {_, {x, ""}} when x >= 0 and x <= 1 ->
        x

      _ ->
        Mix.raise(
          "mix #{@task}: --explore must be activation, untried_first or a probability between 0 and 1, got: #{value}"
        )
    end
  end

  defp text(s, dir) do
    paths =
      for {key, label} <- [{"path1", "Path-1"}, {"path2", "Path-2"}] do
        "  #{label}: mean lap times #{TartarusTools.CLI.show(s.lap_times["mean"][key])}; plateau at lap #{TartarusTools.CLI.show(s.plateau_lap[key])} (#{TartarusTools.CLI.show(s.plateau_time[key])} s)"
      end

    best =
      for type <- ["sp_a", "sp_b", "sp_c", "sp_d"] do
        "  #{type}: #{TartarusTools.CLI.show(s.best_pfa[type])} #{TartarusTools.CLI.show(s.best_pfa_counts[type])}  Table 6.5: #{s.best_pfa_table6_5[type]}  exhaustive: #{TartarusTools.CLI.show(s.exhaustive_best && s.exhaustive_best[type])}"
      end

    Enum.join(
      ["pfa: #{s.trials} trials of #{s.laps} laps"] ++
        paths ++
        best ++
        ["  sim_speed_x #{s.sim_speed_x}", "  written to #{dir}"],
      "\n"
    )
  end
end
