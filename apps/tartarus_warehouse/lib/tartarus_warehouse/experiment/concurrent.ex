defmodule TartarusWarehouse.Experiment.Concurrent do
  @moduledoc """
  `mix tartarus.warehouse --experiment concurrent` (thesis §4.5.5, "Mutual Exclusion for
  Concurrent Tasks"): `--conc-jobs` m jobs of n independent tasks each (task i needs its
  own resource ψ_i, no task after another), every task of the same duration t (no
  jitter), on k robots. The thesis: with n agents and n robots every agent runs its task
  at once, so the m jobs take m·t; with more robots than tasks mutual exclusion still
  holds (an agent uses one robot at a time). Arms: each n of `--conc-tasks` on k = n and
  k = 2n robots; seeds: `--seeds` from `--seed`. Per floor: the makespan over m·t, the
  most tasks running at once, the mean running (the occupancy, Eq. 4.2), violations.
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusWarehouse.Experiment.Jobs

  @impl Experiment
  def kinds, do: [:independent]

  @impl Experiment
  def points(p),
    do: for(n <- p.conc_tasks, k <- [n, 2 * n], s <- Experiment.seeds(p), do: {n, k, s})

  @impl Experiment
  def sweep(state) do
    p = state.p

    %{
      arms: for(n <- p.conc_tasks, k <- [n, 2 * n], do: {arm({n, k}), {n, k}}),
      seeds: Experiment.seeds(%{seed: state.seed, seeds: p.seeds}),
      point: fn {n, k}, seed -> {n, k, seed} end
    }
  end

  defp arm({n, k}), do: "n=#{n} k=#{k}"

  @impl Experiment
  def runs({n, k, seed}, state) do
    p = state.p

    opts = [
      robots: k,
      jobs: Jobs.independent_jobs(p.conc_jobs, n, 2000),
      jitter: 0,
      latency_ms: p.latency_ms,
      service_ms: p.service_ms
    ]

    [{:independent, Experiment.floor(state, seed) ++ opts, %{run_seed: seed}}]
  end

  @doc "What one floor measured: `makespan_ms`, `mt_ms` (m·t), their ratio, `peak`, `mean_running`."
  @spec measure(map(), map()) :: map()
  def measure(r, p) do
    t = 2000 * p.scale
    mt = p.conc_jobs * t
    {a, b} = Experiment.span(r.history)
    makespan = (b - a) / 1000

    %{
      makespan_ms: Float.round(makespan, 3),
      mt_ms: mt,
      over_mt: Float.round(makespan / mt, 4),
      peak: Experiment.peak_concurrency(r.history),
      mean_running:
        Float.round(Enum.sum(Enum.map(r.history, &(&1.stop_us - &1.start_us))) / (b - a), 3)
    }
  end

  @impl Experiment
  def record({n, k, seed}, state) do
    r = Enum.find(state.runs, &(&1.point == {n, k, seed}))

    Series.record(
      state.series,
      "makespan_over_mt_n#{n}_k#{k}",
      seed,
      measure(r, state.p).over_mt
    )
  end

  @impl Experiment
  def summary(base, state) do
    by_arm =
      state.runs
      |> Enum.group_by(fn %{point: {n, k, _}} -> arm({n, k}) end)
      |> Map.new(fn {arm, runs} ->
        ms = Enum.map(runs, &Map.put(measure(&1, state.p), :seed, &1.run_seed))
        median = fn key -> ms |> Enum.map(& &1[key]) |> TartarusTools.Stats.median() end

        {arm,
         %{
           by_seed: Map.new(ms, &{to_string(&1.seed), Map.delete(&1, :seed)}),
           over_mt: median.(:over_mt),
           peak: median.(:peak),
           mean_running: median.(:mean_running),
           violations: runs |> Enum.map(& &1.violations) |> Enum.sum()
         }}
      end)

    Map.merge(base, %{
      speedup: nil,
      conc_jobs: state.p.conc_jobs,
      task_ms: 2000 * state.p.scale,
      latency_ms: state.p.latency_ms,
      service_ms: state.p.service_ms,
      seeds: Experiment.seeds(%{seed: state.seed, seeds: state.p.seeds}),
      concurrency: by_arm
    })
  end

  @impl Experiment
  def gantt(%{kind: :independent, point: {n, k, seed}}, state) do
    if seed == state.seed,
      do:
        {"#{n} independent tasks a job on #{k} robots (§4.5.5), seed #{seed}",
         "gantt_concurrent_n#{n}_k#{k}.svg"}
  end

  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s),
    do:
      Enum.map_join(Enum.sort(s.concurrency), "\n", fn {arm, a} ->
        "#{arm}: makespan / m·t #{a.over_mt}, most tasks at once #{a.peak}, mean running #{a.mean_running}"
      end)
end
