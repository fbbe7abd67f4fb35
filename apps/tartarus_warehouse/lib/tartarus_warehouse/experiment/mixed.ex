defmodule TartarusWarehouse.Experiment.Mixed do
  @moduledoc """
  `mix tartarus.warehouse --experiment mixed` (thesis §4.7.5, Fig. 4.11): 6 jobs on 4
  robots, jobs 1 and 6 purely sequential, jobs 2-5 two independent sequences each: the
  jobs whose two sequences ran at once.
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusWarehouse.Experiment.Jobs

  @impl Experiment
  def kinds, do: [:variable]

  @impl Experiment
  def runs(_point, state) do
    opts = [robots: 4, jobs: Jobs.mixed_jobs(6, 2000), jitter: state.p.jitter]
    [{:variable, Experiment.floor(state) ++ opts, %{}}]
  end

  @impl Experiment
  def summary(base, %{runs: [r]}) do
    overlapping =
      for j <- r.jobs,
          [a, b] <- [
            r.history
            |> Enum.filter(&(&1.job == j))
            |> Enum.group_by(& &1.seq)
            |> Map.values()
          ],
          Experiment.span(a) |> overlaps?(Experiment.span(b)),
          do: j

    Map.merge(base, %{
      speedup: nil,
      jobs_with_concurrent_sequences: overlapping,
      mean_busy_robots: r.occupancy.mean
    })
  end

  defp overlaps?({a0, a1}, {b0, b1}), do: a0 < b1 and b0 < a1

  @impl Experiment
  def gantt(%{kind: :variable}, _state),
    do: {"sequential and independent sequences (Fig. 4.11)", "gantt_mixed.svg"}

  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s),
    do:
      "jobs whose two sequences overlapped: #{TartarusTools.CLI.show(s.jobs_with_concurrent_sequences)}"
end
