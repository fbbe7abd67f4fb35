defmodule TartarusWarehouse.Experiment.Otfp do
  @moduledoc """
  `mix tartarus.warehouse --experiment otfp`: on-the-fly programming (thesis §4.5.4). 6
  warehouse jobs on 3 robots while a task T2A (a detour, its program compiled at run time)
  is added after T2 while job 2 runs T2, deleted, and added again (Fig. 4.12: a Gantt
  chart); then 16 jobs of 10 soft tasks on 4 robots while tasks are added (after 2, 4 and
  6 jobs completed: 1, 1 and 3 tasks) and deleted (3 tasks after 9 jobs): the tasks and
  the time per task of each job (Fig. 4.5).
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusWarehouse.Experiment.Jobs

  @impl Experiment
  def kinds, do: [:variable, :stream]

  @impl Experiment
  def runs(_point, state) do
    p = state.p
    detour = Jobs.detour_program()
    t = &Experiment.scaled(&1, p)
    t2a = %{name: "T2A", resources: [:detour], program: detour, duration_ms: 1500}

    extra = fn i ->
      %{name: "X#{i}", resources: [{:extra, i}], program: detour, duration_ms: 2000}
    end

    floor = Experiment.floor(state)

    [
      {:variable,
       floor ++
         [
           robots: 3,
           jobs: Jobs.thesis_jobs(6, 2000),
           resources: [:bay, :line, :rack, :wall, :packing, :return, :detour],
           jitter: p.jitter,
           events: [
             {{:ms, t.(45)}, {:insert, "T2", t2a}},
             {{:ms, t.(95)}, {:delete, "T2A"}},
             {{:ms, t.(135)}, {:insert, "T2", t2a}}
           ]
         ], %{}},
      {:stream,
       floor ++
         [
           robots: 4,
           jobs: Jobs.soft_jobs(16, 10, 2000),
           resources: Enum.map(1..10, &{:psi, &1}) ++ Enum.map(1..5, &{:extra, &1}),
           events: [
             {2, {:insert, "T10", extra.(1)}},
             {4, {:insert, "T5", extra.(2)}},
             {6, {:insert, "T3", extra.(3)}},
             {6, {:insert, "T7", extra.(4)}},
             {6, {:insert, "T8", extra.(5)}},
             {9, {:delete, "X3"}},
             {9, {:delete, "X4"}},
             {9, {:delete, "X5"}}
           ]
         ], %{}}
    ]
  end

  @impl Experiment
  def record(_point, state) do
    stream = Enum.find(state.runs, &(&1.kind == :stream))

    Enum.reduce(per_job(stream), state.series, fn {job, tasks, ms_per_task}, series ->
      series
      |> Series.record(:tasks_in_job, job, tasks)
      |> Series.record(:ms_per_task, job, ms_per_task)
    end)
  end

  # Per job of a run: tasks run (not skipped) and the job's time per task.
  defp per_job(r) do
    r.history
    |> Enum.reject(& &1.skipped)
    |> Enum.group_by(& &1.job)
    |> Enum.sort()
    |> Enum.map(fn {job, es} ->
      {t0, t1} = Experiment.span(es)
      {job, length(es), Float.round((t1 - t0) / 1000 / length(es), 3)}
    end)
  end

  @impl Experiment
  def charts(state),
    do: [
      %{
        file: "otfp",
        title: "Tasks per job as tasks are added and deleted (Fig. 4.5)",
        subtitle:
          "16 jobs of 10 tasks on 4 robots, time scale #{state.p.scale}, seed #{state.seed}",
        series: [:tasks_in_job],
        labels: %{tasks_in_job: "tasks in the job"},
        x_label: "job",
        y_label: "tasks",
        y_min: 0
      },
      %{
        file: "otfp_ms",
        title: "Time per task as tasks are added and deleted (Fig. 4.5)",
        subtitle:
          "16 jobs of 10 tasks on 4 robots, time scale #{state.p.scale}, seed #{state.seed}",
        series: [:ms_per_task],
        labels: %{ms_per_task: "ms per task"},
        x_label: "job",
        y_label: "time per task",
        y_unit: "ms",
        y_min: 0
      }
    ]

  @impl Experiment
  def summary(base, state) do
    [gantt] = Enum.filter(state.runs, &(&1.kind == :variable))
    stream = Enum.find(state.runs, &(&1.kind == :stream))

    Map.merge(base, %{
      speedup: nil,
      inserted_runs: Enum.count(gantt.history, &(&1.task == "T2A")),
      jobs_with_t2a:
        gantt.history
        |> Enum.filter(&(&1.task == "T2A"))
        |> Enum.map(& &1.job)
        |> Enum.uniq()
        |> Enum.sort(),
      skipped_runs: Enum.count(stream.history ++ gantt.history, & &1.skipped),
      tasks_in_job: Experiment.by(state, :tasks_in_job),
      ms_per_task: Experiment.by(state, :ms_per_task)
    })
  end

  @impl Experiment
  def gantt(%{kind: :variable}, _state),
    do: {"T2A added, deleted and added again on the fly (Fig. 4.12)", "gantt_otfp.svg"}

  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s),
    do:
      "tasks per job: #{TartarusTools.CLI.show(s.tasks_in_job)}\nms per task: #{TartarusTools.CLI.show(s.ms_per_task)}"
end
