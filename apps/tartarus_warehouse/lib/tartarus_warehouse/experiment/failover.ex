defmodule TartarusWarehouse.Experiment.Failover do
  @moduledoc """
  `mix tartarus.warehouse --experiment failover`, beyond the thesis: 10 warehouse jobs on
  3 robots while the distributor's host is killed twice (100 ms and 50 ms down, at the
  default scale) and started again on its journal, for three seeds (seed, seed + 1,
  seed + 2): jobs lost, jobs duplicated (a task run twice), violations; and once without
  persistence, for contrast (not counted in `jobs`, `completed_jobs`, `deadlocks`,
  `tasks`).
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusWarehouse.Experiment.Jobs

  @impl Experiment
  def kinds, do: [:variable, :no_persistence]

  @impl Experiment
  def points(_p), do: [1, 2, 3]

  # The three points are three seeds: one arm, the seeds seed..seed + 2 (point i runs on
  # seed + i - 1).
  @impl Experiment
  def sweep(state) do
    %{
      arms: [{"kills", nil}],
      seeds: Enum.map(points(state.p), &(state.seed + &1 - 1)),
      point: fn nil, seed -> seed - state.seed + 1 end
    }
  end

  @impl Experiment
  def runs(i, state) do
    p = state.p
    jobs = Jobs.thesis_jobs(10, 2000)
    t = &Experiment.scaled(&1, p)
    seed = state.seed + i - 1

    kills = [
      {{:ms, t.(40 + 20 * i)}, {:kill_distributor, t.(100)}},
      {{:ms, t.(240 + 20 * i)}, {:kill_distributor, t.(50)}}
    ]

    floor = [robots: 3, jobs: jobs, scale: p.scale, seed: seed, mode: p.mode]

    kept =
      {:variable,
       floor ++ [jitter: p.jitter, timeout_ms: p.timeout_ms, failover: true, events: kills],
       %{run_seed: seed}}

    # The same loss without persistence: the distributor and what it knew are gone.
    lost =
      {:no_persistence, floor ++ [timeout_ms: t.(2000), events: [hd(kills)]], %{run_seed: seed}}

    if i == 1, do: [kept, lost], else: [kept]
  end

  @impl Experiment
  def record(i, state) do
    r = Enum.find(state.runs, &(&1.point == i and &1.kind == :variable))

    state.series
    |> Series.record(:jobs_lost, i, length(r.jobs) - r.completed_jobs)
    |> Series.record(:makespan_ms, i, round(r.makespan_ms))
  end

  @impl Experiment
  def summary(base, state) do
    kept = Enum.filter(state.runs, &(&1.kind == :variable))
    lost = Enum.find(state.runs, &(&1.kind == :no_persistence))

    duplicated = fn r ->
      r.history
      |> Enum.frequencies_by(&{&1.job, &1.task})
      |> Enum.count(fn {_, n} -> n > 1 end)
    end

    Map.merge(base, %{
      speedup: nil,
      seeds: Enum.map(kept, & &1.run_seed),
      kills: kept |> Enum.map(&length(&1.killed_at_us)) |> Enum.sum(),
      jobs_lost: kept |> Enum.map(&(length(&1.jobs) - &1.completed_jobs)) |> Enum.sum(),
      jobs_duplicated: kept |> Enum.map(duplicated) |> Enum.sum(),
      jobs_lost_by_seed:
        Map.new(kept, &{to_string(&1.run_seed), length(&1.jobs) - &1.completed_jobs}),
      makespan_ms_by_seed: Map.new(kept, &{to_string(&1.run_seed), round(&1.makespan_ms)}),
      jobs_lost_without_persistence: length(lost.timed_out),
      # The runs without persistence are not counted in jobs/completed_jobs/deadlocks.
      jobs: kept |> Enum.map(&length(&1.jobs)) |> Enum.sum(),
      completed_jobs: kept |> Enum.map(& &1.completed_jobs) |> Enum.sum(),
      deadlocks: kept |> Enum.map(&length(&1.timed_out)) |> Enum.sum(),
      tasks: kept |> Enum.map(&length(&1.history)) |> Enum.sum()
    })
  end

  @impl Experiment
  def gantt(%{kind: :variable, run_seed: seed}, _state),
    do: {"the distributor's host killed twice, seed #{seed}", "gantt_failover_seed_#{seed}.svg"}

  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s),
    do:
      "kills #{s.kills}: jobs lost #{s.jobs_lost}, duplicated #{s.jobs_duplicated} (without persistence: #{s.jobs_lost_without_persistence} lost)"
end
