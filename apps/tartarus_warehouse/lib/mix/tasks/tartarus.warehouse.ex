defmodule Mix.Tasks.Tartarus.Warehouse do
  @shortdoc "Warehouse: mutual exclusion by a clock-less pipeline of task agents (thesis ch. 4)"
  @moduledoc """
  Runs the warehouse experiments of the thesis (§4.7) on emulated floors (see
  `TartarusWarehouse.Experiment`; the experiment named by `--experiment` is found in its
  registry, `TartarusWarehouse.Experiment.experiments/0`, one module each): task agents carry each task's program and are the
  tokens of its resources; robots line up into a clock-less pipeline.

      mix tartarus.warehouse [--experiment robots|scaling|otfp|removal|mixed|failover|concurrent|manet]
                             [--seed 1] [--out DIR] [--json] [--scale 0.01] [--mode virtual|peer]
                             [--robots 4] [--jobs 4] [--jitter 0.3] [--equal-jobs 40]
                             [--sizes 5,10,20,30,45,60] [--scaling-jobs 120|n+20] [--nodes 100]
                             [--scaling-robots 60] [--phi-nodes 20] [--seeds 3] [--drop 10]
                             [--designs central,agents,agents_continue,guided,guided_continue]
                             [--latency-ms 0] [--service-ms 2.2] [--big-robots 1000]
                             [--conc-tasks 2,4] [--conc-jobs 5] [--churn 0,0.1]
                             [--manet-robots 4] [--manet-jobs 8]
                             [--time real|virtual] [--timeout-ms 300000] [--dashboard PORT]

  `--scale` is the time scale: a task of the thesis's ideal 2 s runs as `2000 * scale` ms
  (default 0.01: 20 ms). `--dashboard PORT` serves the web dashboard on 127.0.0.1:PORT
  while the experiment runs (the address and token are printed): the hosts of the floor
  running now and the warehouse panel (`TartarusWarehouse.Panel`: each robot's state, the
  tasks it runs and the agent it serves, the jobs done, the mutual-exclusion check so
  far); add `--scale 1` to watch the thesis's 2 s tasks in real time. `--help` prints this
  text. Experiments:

    * `robots`: `--jobs` (4) warehouse jobs of T1-T4 with variable durations (each robot
      its own pace, each execution a spread of `--jitter`) on 1..`--robots` robots: a
      Gantt chart per robot count (`gantt_<k>_robots.svg`, Figs. 4.7-4.10) and the
      speed-up over one robot (`speedup.svg`, against the thesis's 1.75, 1.84, 2.21); then
      `--equal-jobs` (40) jobs with equal durations: the pipeline's steady-state speed-up;
    * `scaling` (Fig. 4.4 under the thesis's load, default `--scale 0.1`): for each job
      size of `--sizes` and each of `--seeds` seeds (seed, seed + 1, ...), `--scaling-jobs`
      jobs of that many soft tasks (Sort, Merge, Add, Sub, Div repeating), all submitted
      at the start, on a `--nodes`-node network (`jd`, `--scaling-robots` robots,
      `--phi-nodes` shared-resource nodes, the rest secondary) with the floors of
      `--designs`: the central server (3 messages a task), the blind task agents (the
      thesis's) returning to the distributor after each block or continuing to the next
      job's robot, the guided agents likewise; `--service-ms S` is the time the central
      server and the Job Distributor each take for every message they handle
      (`TartarusWarehouse.Service`); `--latency-ms L` gives every link a one-way delay paid
      alike by both designs. The metric is the steady state's time per task (each job's
      span over its tasks, the first and last `--drop` jobs left out), medians over the
      seeds: `avg_task_time.svg` (with the utilisation formula's prediction),
      `service_queue.svg` and `service_busy.svg` (the central processes over time, at the
      largest size); with `--big-robots N` also one run on N robots (20 jobs of 5 tasks in
      20 independent pipelines, agents guided by signal fields; `big_run` in the summary);
    * `otfp`: a task added, deleted and added again while 6 jobs run on 3 robots
      (`gantt_otfp.svg`, Fig. 4.12), then 16 jobs of 10 soft tasks while tasks are added
      and deleted (`otfp.svg`: tasks of each job, `otfp_ms.svg`: its ms per task, Fig. 4.5);
    * `removal`: 10 jobs on 3 robots; r2 leaves once 2 jobs completed (battery low: it
      finishes its job first), a fourth robot joins once 6 completed
      (`gantt_removal_seed_S.svg`, Fig. 4.13), on `--seeds` seeds; each robot's utilisation
      before r2 left, between, and after r4 joined;
    * `mixed`: jobs of sequential and independent sequences (`gantt_mixed_seed_S.svg`, Fig.
      4.11), on `--seeds` seeds; each job's span and its span over its tasks' times;
    * `concurrent` (§4.5.5): `--conc-jobs` m jobs of n independent tasks (n of
      `--conc-tasks`) of equal time t on n and 2n robots, on `--seeds` seeds: the makespan
      over m·t, the most tasks at once (`gantt_concurrent_n<n>_k<k>.svg`);
    * `manet` (§4.3): `--manet-jobs` jobs on `--manet-robots` robots linked only through
      as many Σ nodes and `jd`, while robots and Σ nodes leave the network and rejoin it
      (each node up leaves with probability p of `--churn` a tick of a quarter task, rejoins
      with 1/2 a tick), on `--seeds` seeds: violations, jobs done and not done
      (`gantt_manet.svg`);
    * `failover`: the distributor's host killed twice during 10 jobs and started again on
      its journal, for seeds S, S+1, S+2; once more without persistence, for contrast.

  Output (in `--out DIR`, default `results/warehouse-<experiment>-<UTC timestamp>`):
  `executions.csv` (every task executed: robot, job, task, resources, start, stop), the
  Gantt charts (one lane per robot), the series as CSV and SVG, `summary.json` and
  `summary.md`; and in `sweep/` what `TartarusEmu.Sweep` writes for the experiment's runs
  (an arm a point: a robot count, a job size; for `failover` one arm on seeds S..S+2):
  `runs.csv` (each run's makespan per floor kind, completed jobs, violations, deadlocks),
  its own `summary.json` and `summary.md`.

  Summary keys (all experiments): `experiment, jobs, tasks, completed_jobs,
  mutex_violations` (Eq. 4.1, pairs of executions on two robots holding one resource at
  one instant), `deadlocks` (jobs not completed within `--timeout-ms`), `speedup` (for
  `robots` an object keyed by robot count, else null), `scale, mode, wall_ms` and the
  runner's `scenario, seed, steps, setup_ms, run_ms` (`steps` is 1: the sweep), and
  `sweep` (`name, seeds, arms, runs`, the per-arm `aggregates` of `TartarusEmu.Sweep`). `robots` adds `speedup_equal,
  makespan_variable_ms, makespan_equal_ms, speedup_thesis, jobs_variable, jobs_equal,
  jitter`; `scaling` adds `avg_task_ms_central, avg_task_ms_agents,
  avg_task_ms_agents_continue, avg_task_ms_agents_guided, avg_task_ms_agents_guided_continue`
  (medians over the seeds, keyed by tasks per job), `avg_task_ms_by_seed`, `utilisation`
  and `max_queue` (the central server's and each design's distributor's, medians over the
  seeds, keyed by tasks per job), `predicted_knee, predicted_central_ms, central_fit`
  (`knee, a, b, sse` of the hinge fit), `central_rise` (the largest size over the
  minimum), `crossings` (per agents' design: `below_at`, `below_from`), `pass` (`rise,
  knee, exclusion`), `latency_ms, service_ms, nodes, robots, phi_nodes, jobs_per_run,
  drop, seeds, big_run`; `otfp` adds `inserted_runs,
  jobs_with_t2a, skipped_runs, tasks_in_job, ms_per_task`; `removal` adds `jobs_per_robot,
  removed_robot, joined_robot, mean_busy_robots`; `mixed` adds
  `jobs_with_concurrent_sequences, mean_busy_robots`; `failover` adds `jobs_lost,
  jobs_duplicated, kills, seeds, jobs_lost_by_seed, makespan_ms_by_seed,
  jobs_lost_without_persistence`. With `--json` the last line printed is the summary as
  one JSON object.
  """
  use TartarusTools.CLI

  alias TartarusWarehouse.Experiment

  @task "tartarus.warehouse"

  @impl true
  def run(argv) do
    # The flags are the experiment's schema.
    schema =
      Experiment.schema()
      |> Keyword.drop([:quiet])
      |> Keyword.update!(:experiment, &Keyword.put(&1, :default, :robots))
      |> Keyword.update!(:out, &Keyword.put(&1, :type, :string))
      |> Keyword.update!(:dashboard, &Keyword.put(&1, :type, :non_neg_integer))
      # Typed as flags: --scale 0.1, --sizes 5,10,60, --designs central,guided
      |> Keyword.update!(:scale, &(&1 |> Keyword.put(:type, :number) |> Keyword.delete(:default)))
      |> Keyword.update!(:sizes, &Keyword.put(&1, :type, :string))
      |> Keyword.update!(:conc_tasks, &Keyword.put(&1, :type, :string))
      |> Keyword.update!(:churn, &Keyword.put(&1, :type, :string))
      |> Keyword.update!(:designs, &Keyword.put(&1, :type, :string))
      |> Keyword.update!(:scaling_jobs, &Keyword.put(&1, :type, :string))
      |> Keyword.put(:json, type: :boolean, default: false, doc: "print the summary as JSON")

    opts = argv |> TartarusTools.CLI.options!(schema, @task) |> lists!()
    {experiment, mode, json?} = {opts[:experiment], opts[:mode], opts[:json]}
    exp_opts = opts |> Keyword.drop([:json]) |> Keyword.put(:quiet, json?)

    exp_opts = if opts[:out], do: exp_opts, else: Keyword.delete(exp_opts, :out)

    case Experiment.validate(exp_opts) do
      {:ok, _} -> :ok
      {:error, message} -> TartarusTools.CLI.error!(@task, message)
    end

    Mix.Task.run("app.start")

    unless json?,
      do:
        Mix.shell().info(
          "warehouse: experiment #{experiment}, seed #{opts[:seed]}, #{mode} hosts..."
        )

    case Experiment.run(exp_opts) do
      {:ok, %{summary: s, out: dir}} ->
        TartarusTools.CLI.report(s, [json: json?], fn s -> text(s, dir) end)

      {:error, message} ->
        TartarusTools.CLI.error!(@task, message)
    end
  end

  # --sizes and --designs: comma-separated lists (a default is already a list); --scaling-jobs:
  # a count or a·n + b ("2n+20", "n+20", "120").
  defp lists!(opts) do
    opts
    |> Keyword.update!(:scaling_jobs, fn
      n when is_integer(n) ->
        n

      text ->
        compact = String.replace(text, " ", "")

        case {Integer.parse(compact), Regex.run(~r/^(\d*)n(?:\+(\d+))?$/, compact)} do
          {{n, ""}, _} when n > 0 -> n
          {_, [_, a]} -> per_size(a, "")
          {_, [_, a, b]} -> per_size(a, b)
          _ -> bad_jobs!(text)
        end
    end)
    |> Keyword.update!(:sizes, &numbers!(&1, "--sizes", "positive integers", :pos))
    |> Keyword.update!(:conc_tasks, &numbers!(&1, "--conc-tasks", "positive integers", :pos))
    |> Keyword.update!(:churn, &numbers!(&1, "--churn", "probabilities (0 to 1)", :prob))
    |> Keyword.update!(:designs, fn
      list when is_list(list) ->
        list

      text ->
        known = [:central, :agents, :agents_continue, :guided, :guided_continue]

        Enum.map(String.split(text, ",", trim: true), fn x ->
          case Enum.find(known, &(to_string(&1) == String.trim(x))) do
            nil ->
              TartarusTools.CLI.error!(
                @task,
                "--designs: expected some of #{Enum.join(known, ", ")} separated by commas, got: #{inspect(text)}"
              )

            d ->
              d
          end
        end)
    end)
  end

  # A comma-separated list of numbers (a default is already a list): positive integers
  # (`:pos`) or probabilities (`:prob`).
  defp numbers!(list, _flag, _what, _kind) when is_list(list), do: list

  defp numbers!(text, flag, what, kind) do
    Enum.map(String.split(text, ",", trim: true), fn x ->
      case {kind, Integer.parse(String.trim(x)), Float.parse(String.trim(x))} do
        {:pos, {n, ""}, _} when n > 0 ->
          n

        {:prob, _, {p, ""}} when p >= 0 and p <= 1 ->
          p

        _ ->
          TartarusTools.CLI.error!(
            @task,
            "#{flag}: expected #{what} separated by commas, got: #{inspect(text)}"
          )
      end
    end)
  end

  defp per_size(a, b),
    do:
      {:per_size, if(a == "", do: 1, else: String.to_integer(a)),
       if(b == "", do: 0, else: String.to_integer(b))}

  defp bad_jobs!(text),
    do:
      TartarusTools.CLI.error!(
        @task,
        "--scaling-jobs: expected a positive count (120) or a count per size (n+20, 2n+20), got: #{inspect(text)}"
      )

  # The experiment's own lines (its module, from the registry), then the common ones.
  defp text(s, dir) do
    lines = Experiment.module(String.to_existing_atom(s.experiment)).text(s)

    """
    jobs #{s.jobs}, completed #{s.completed_jobs}, tasks run #{s.tasks}, mutex violations #{s.mutex_violations}, deadlocks #{s.deadlocks}
    #{lines}
    written to #{dir}\
    """
  end
end
