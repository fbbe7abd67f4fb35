defmodule Mix.Tasks.Tartarus.Arena do
  @shortdoc "Robot arena: each path-following algorithm on the paths of §6.5.11, pictures, simulator speed"
  @moduledoc """
  Runs `TartarusArena.Experiment`: each path-following algorithm (A1-A8, Table 6.4) for
  laps on both paths of §6.5.11 at once, each over every sub-path instance, arena pictures,
  and the simulator's speed with three robots.

      mix tartarus.arena [--experiment arena|sensitivity] [--seed 1] [--laps 3]
                         [--bench-seconds 120] [--seeds 5] [--footprint 0.015]
                         [--accel 0.5] [--corner-radius 0.05] [--pfas A1,..,A8]
                         [--out DIR] [--json]

  Output (in `--out DIR`, default `results/arena-<UTC timestamp>`): `lap_times.csv` (pfa,
  path, lap, seconds), `subpaths.csv` (pfa, path, sub-path index and type, completed,
  time, on_line, cost), `trajectories_A1.svg` .. `trajectories_A8.svg`, `snapshot.svg`,
  `bench_snapshot.svg`, `camera.png` (the whole arena from above), `runs.csv` (a row per
  PFA: mean lap time and put-backs per path, mean sub-path cost), `summary.json`,
  `summary.md`.

  Summary keys: `seed, laps, lap_times` (per PFA, per path), `lost` (times a robot left
  the line and was put back, per PFA and path), `path_length_m, subpath_cost` (mean cost
  per sub-path type and PFA), `exhaustive_best` (the PFA of least cost per sub-path type:
  what trying every PFA everywhere finds), `sim_speed_x` (simulated seconds per wall
  second with `sim_speed_robots` = 3 robots), `sim_speed_cpu_x` (the same against the VM's
  CPU time, which a busy machine does not inflate), `bench_seconds, wall_ms`, `sweep`
  (the numbers of `runs.csv` per PFA). With `--json` the
  last line printed is the summary as one JSON object. `--help` prints this text.

  `--experiment sensitivity` (`TartarusArena.Sensitivity`, issue 46 item 8) runs instead
  the exhaustive per-sub-path ranking (every PFA alone over every sub-path instance) under
  five conditions: `kinematic` (the arena as it is), `footprint` (line sensors seeing a
  disc of radius `--footprint` m), `inertia` (wheels limited to `--accel` m/s²),
  `rounded` (the paths' corners rounded to `--corner-radius` m) and `all` (the three),
  `--seeds` runs each on seeds `--seed`, `--seed` + 1, ..., ranking the PFAs of `--pfas`
  (all eight by default; fewer for a quick look) (`--laps` and
  `--bench-seconds` are not used). Output: `runs.csv` (a row per sub-path run: condition,
  seed, pfa, path, index, type, completed, time, on_line, cost), `ranking.svg` (the
  least-cost PFA per type and condition beside Table 6.5), box plots per condition,
  `summary.json`, `summary.md`. Summary keys: `seeds, footprint, accel, corner_radius,
  table6_5, conditions` (per condition: `cost` per type and PFA, `ranking`, `best`,
  `failed`, `best_per_seed`, `matches` with Table 6.5), `supported` (per changed
  condition: A2 the least-cost PFA on sp-b or sp-d), `table6_5_reproduced`, `sweep`.
  """
  use TartarusTools.CLI

  alias TartarusArena.{Experiment, Sensitivity}

  @task "tartarus.arena"

  @impl true
  def run(argv) do
    schema =
      [
        experiment: [
          type: {:in, [:arena, :sensitivity]},
          default: :arena,
          doc: "the laps and sub-path costs of every PFA, or Table 6.5's sensitivity"
        ]
      ] ++
        Experiment.schema() ++
        Keyword.take(Sensitivity.schema(), [:seeds, :footprint, :accel, :corner_radius, :pfas])

    schema =
      schema
      |> Keyword.update!(:out, &Keyword.put(&1, :type, :string))
      |> Keyword.update!(
        :pfas,
        &Keyword.merge(&1, type: :string, default: "A1,A2,A3,A4,A5,A6,A7,A8")
      )
      |> Keyword.put(:json, type: :boolean, default: false, doc: "print the summary as JSON")

    opts = TartarusTools.CLI.options!(argv, schema, @task)
    json? = opts[:json]
    Mix.Task.run("app.start")

    if opts[:experiment] == :sensitivity,
      do: sensitivity(opts, json?),
      else: arena(opts, json?)
  end

  defp sensitivity(opts, json?) do
    sens_opts =
      opts
      |> Keyword.take([:seeds, :seed, :footprint, :accel, :corner_radius, :out])
      |> Enum.reject(fn {_, v} -> v == nil end)
      |> Keyword.put(:pfas, parse_pfas!(opts[:pfas]))
      |> Keyword.put(:quiet, json?)

    case Sensitivity.run(sens_opts) do
      {:ok, %{summary: s, out: dir}} ->
        TartarusTools.CLI.report(s, [json: json?], fn s ->
          "# Table 6.5's sensitivity\n\n" <> Sensitivity.markdown(s) <> "\nOutputs in #{dir}"
        end)

      {:error, message} ->
        TartarusTools.CLI.error!(@task, message)
    end
  end

  defp arena(opts, json?) do
    exp_opts =
      opts
      |> Keyword.drop([:json, :experiment, :seeds, :footprint, :accel, :corner_radius, :pfas])
      |> Enum.reject(fn {_, v} -> v == nil end)

    unless json?,
      do: Mix.shell().info("arena: seed #{opts[:seed]}, #{opts[:laps]} laps per PFA...")

    case Experiment.run(exp_opts) do
      {:ok, %{summary: s, out: dir}} ->
        TartarusTools.CLI.report(s, [json: json?], fn s ->
          "# Arena run (seed #{s.seed})\n\n" <> Experiment.markdown(s) <> "\nOutputs in #{dir}"
        end)

      {:error, message} ->
        TartarusTools.CLI.error!(@task, message)
    end
  end

  defp parse_pfas!(text) do
    names = text |> String.split(",", trim: true) |> Enum.map(&String.upcase(String.trim(&1)))

    if names != [] and Enum.all?(names, &TartarusArena.PFAs.by_name/1),
      do: Enum.uniq(names),
      else:
        Mix.raise(
          "mix #{@task}: invalid value for --pfas: expected comma-separated names A1 to A8, got: #{inspect(text)}"
        )
  end
end
