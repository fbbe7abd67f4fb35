defmodule Mix.Tasks.Tartarus.Arena do
  @shortdoc "Robot arena: each path-following algorithm on the paths of §6.5.11, pictures, simulator speed"
  @moduledoc """
  Runs `TartarusArena.Experiment`: each path-following algorithm (A1-A8, Table 6.4) for
  laps on both paths of §6.5.11 at once, each over every sub-path instance, arena pictures,
  and the simulator's speed with three robots.

      mix tartarus.arena [--seed 1] [--laps 3] [--bench-seconds 120] [--out DIR] [--json]

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
  """
  use TartarusTools.CLI

  alias TartarusArena.Experiment

  @task "tartarus.arena"

  @impl true
  def run(argv) do
    schema =
      Experiment.schema()
      |> Keyword.update!(:out, &Keyword.put(&1, :type, :string))
      |> Keyword.put(:json, type: :boolean, default: false, doc: "print the summary as JSON")

    opts = TartarusTools.CLI.options!(argv, schema, @task)
    json? = opts[:json]
    exp_opts = opts |> Keyword.drop([:json]) |> Enum.reject(fn {_, v} -> v == nil end)
    Mix.Task.run("app.start")

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
end
