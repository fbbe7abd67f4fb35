defmodule TartarusWarehouse.Experiment.Mixed do
  @moduledoc """
  `mix tartarus.warehouse --experiment mixed` (thesis §4.7.5, Fig. 4.11): 6 jobs on 4
  robots, jobs 1 and 6 purely sequential (T1-T4), jobs 2-5 two independent sequences
  each (Fetch -> Carry -> Pack, Stamp -> Place), on `--seeds` seeds (seed, seed + 1, ...:
  the sweep's seeds, one arm). Per seed: each job's span, its span over the sum of its
  tasks' times (below 1: its sequences ran at once), the jobs whose two sequences
  overlapped in time, each robot's utilisation over the run, and a Gantt chart.
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusWarehouse.Experiment.Jobs

  @impl Experiment
  def kinds, do: [:variable]

  @impl Experiment
  def points(p), do: Experiment.seeds(p)

  @impl Experiment
  def sweep(state), do: Experiment.seed_sweep("mixed", state)

  @impl Experiment
  def runs(seed, state) do
    opts = [
      robots: 4,
      jobs: Jobs.mixed_jobs(6, 2000),
      jitter: state.p.jitter,
      latency_ms: state.p.latency_ms
    ]

    [{:variable, Experiment.floor(state, seed) ++ opts, %{run_seed: seed}}]
  end

  @impl Experiment
  def record(seed, state) do
    r = Enum.find(state.runs, &(&1.point == seed))
    Series.record(state.series, :jobs_with_concurrent_sequences, seed, length(overlapping(r)))
  end

  @doc """
  The jobs of a run whose two sequences overlapped in time (ran at once, in part).
  """
  @spec overlapping(map()) :: [term()]
  def overlapping(r) do
    for j <- r.jobs,
        [a, b] <- [
          r.history
          |> Enum.filter(&(&1.job == j))
          |> Enum.group_by(& &1.seq)
          |> Map.values()
        ],
        Experiment.span(a) |> overlaps?(Experiment.span(b)),
        do: j
  end

  @impl Experiment
  def summary(base, state) do
    by_seed = fn f -> Map.new(state.runs, &{to_string(&1.run_seed), f.(&1)}) end

    ratio = fn r ->
      spans = Experiment.job_spans(r.history)

      Map.new(spans, fn {j, ms} ->
        serial = r.history |> Enum.filter(&(&1.job == j)) |> Enum.map(& &1.ms) |> Enum.sum()
        {to_string(j), Float.round(ms / serial, 3)}
      end)
    end

    Map.merge(base, %{
      speedup: nil,
      seeds: Enum.map(state.runs, & &1.run_seed),
      job_span_ms:
        by_seed.(fn r ->
          Map.new(Experiment.job_spans(r.history), &{to_string(elem(&1, 0)), elem(&1, 1)})
        end),
      span_over_serial: by_seed.(ratio),
      jobs_with_concurrent_sequences: by_seed.(&overlapping/1),
      robots_per_job: by_seed.(&robots_per_job/1),
      utilisation:
        by_seed.(fn r ->
          Experiment.utilisation(r.history, r.robots, Experiment.span(r.history))
        end),
      mean_busy_robots: by_seed.(& &1.occupancy.mean)
    })
  end

  defp robots_per_job(r) do
    r.history
    |> Enum.group_by(& &1.job, & &1.robot)
    |> Map.new(fn {j, rs} -> {to_string(j), rs |> Enum.uniq() |> Enum.sort()} end)
  end

  defp overlaps?({a0, a1}, {b0, b1}), do: a0 < b1 and b0 < a1

  @impl Experiment
  def gantt(%{kind: :variable, run_seed: seed}, _state),
    do:
      {"sequential and independent sequences (Fig. 4.11), seed #{seed}",
       "gantt_mixed_seed_#{seed}.svg"}

  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s),
    do:
      "jobs whose two sequences overlapped, by seed: #{TartarusTools.CLI.show(s.jobs_with_concurrent_sequences)}"
end
