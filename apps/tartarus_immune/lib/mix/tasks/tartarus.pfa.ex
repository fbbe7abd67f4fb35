defmodule Mix.Tasks.Tartarus.Pfa do
  @shortdoc "Robots learn which path-following algorithm suits which sub-path (thesis §6.5.11)"
  @moduledoc """
  Runs the path-following experiment of thesis §6.5.11 (see
  `TartarusImmune.PathFollowing.Experiment`): two robots drive Path-1 and Path-2 of the
  arena at once; at each sub-path a robot's host emits a danger signal carrying the
  sub-path's features, iPkts carrying PFA-to-sub-path mappings are drawn to it, the host's
  localized idiotypic network picks one, the robot runs that PFA and its measured cost
  (time, staying on the line) feeds back; each robot receives one new random PFA per lap;
  the mappings travel between the robots as agents.

      mix tartarus.pfa [--laps 12] [--trials 10] [--seed 1] [--out DIR] [--json]
                       [--no-sharing] [--no-danger] [--no-exhaustive]

  Output (in `--out DIR`, default `results/pfa-<UTC timestamp>`): `lap_times.csv` (trial,
  seed, path, lap, seconds), `lap_times_trial1.svg` (one trial, Fig. 6.13a),
  `lap_times_mean.svg` (the mean over trials, Fig. 6.13b), `choices.csv` (every sub-path
  crossed: the PFA used and its measure), `best_pfa.csv` (the best PFA per sub-path type
  beside Table 6.5 and the exhaustive search), `summary.json`, `summary.md`.

  Summary keys: `trials, laps, lap_times` (`trial1`, `mean` and `per_trial`, each per
  path), `plateau_lap` (per path: on the mean curve, the first lap L such that every lap
  from L to the last is within 10% of the mean of the last 3 laps), `plateau_time` (the
  mean lap time from there), `plateau_lap_per_trial`, `best_pfa` (per sub-path type: the
  most frequent network choice over the trials) and `best_pfa_counts`,
  `best_pfa_table6_5`, `exhaustive_best` and `exhaustive_costs` (every PFA alone over
  every sub-path instance of the first seed), `matches_exhaustive`, `matches_table6_5`,
  `counters` (iPkts injected, born, died, migrations, ...), `sim_seconds`,
  `wall_seconds`, `sim_speed_x` (simulated seconds per wall second, immune network
  included). With `--json` the last line printed is the summary as one JSON object.

  `--help` prints this text.
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
      |> Keyword.put(:json, type: :boolean, default: false, doc: "print the summary as JSON")

    opts = TartarusTools.CLI.options!(argv, schema, @task)
    json? = opts[:json]
    exp_opts = Keyword.drop(opts, [:json])
    exp_opts = if opts[:out], do: exp_opts, else: Keyword.delete(exp_opts, :out)
    Mix.Task.run("app.start")

    case Experiment.run(exp_opts) do
      {:ok, %{summary: s, out: dir}} ->
        TartarusTools.CLI.report(s, [json: json?], fn s -> text(s, dir) end)

      {:error, message} ->
        Mix.raise("mix #{@task}: #{message}")
    end
  end

  defp text(s, dir) do
    paths =
      for {key, label} <- [{"path1", "Path-1"}, {"path2", "Path-2"}] do
        "  #{label}: mean lap times #{inspect(s.lap_times["mean"][key])}; plateau at lap #{inspect(s.plateau_lap[key])} (#{inspect(s.plateau_time[key])} s)"
      end

    best =
      for type <- ["sp_a", "sp_b", "sp_c", "sp_d"] do
        "  #{type}: #{inspect(s.best_pfa[type])} #{inspect(s.best_pfa_counts[type])}  Table 6.5: #{s.best_pfa_table6_5[type]}  exhaustive: #{inspect(s.exhaustive_best && s.exhaustive_best[type])}"
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
