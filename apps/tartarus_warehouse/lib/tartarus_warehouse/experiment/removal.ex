defmodule TartarusWarehouse.Experiment.Removal do
  @moduledoc """
  `mix tartarus.warehouse --experiment removal` (thesis Fig. 4.13): 8 warehouse jobs on 3
  robots; robot r2's battery runs low once 2 jobs completed (it finishes its job and
  leaves), and a fourth robot joins once 4 jobs completed: the jobs each robot ran.
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusWarehouse.Experiment.Jobs

  @impl Experiment
  def kinds, do: [:variable]

  @impl Experiment
  def runs(_point, state) do
    opts = [
      robots: 4,
      standby: [4],
      jobs: Jobs.thesis_jobs(8, 2000),
      jitter: state.p.jitter,
      events: [{2, {:retire, 2}}, {4, {:join, 4}}]
    ]

    [{:variable, Experiment.floor(state) ++ opts, %{}}]
  end

  @impl Experiment
  def summary(base, %{runs: [r]}) do
    jobs_of = fn robot ->
      r.history
      |> Enum.filter(&(&1.robot == robot))
      |> Enum.map(& &1.job)
      |> Enum.uniq()
      |> Enum.sort()
    end

    Map.merge(base, %{
      speedup: nil,
      removed_robot: "r2",
      joined_robot: "r4",
      jobs_per_robot: Map.new(r.robots, &{&1, jobs_of.(&1)}),
      mean_busy_robots: r.occupancy.mean
    })
  end

  @impl Experiment
  def gantt(%{kind: :variable}, _state),
    do: {"r2 leaves after 2 jobs, r4 joins after 4 (Fig. 4.13)", "gantt_removal.svg"}

  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s), do: "jobs per robot: #{TartarusTools.CLI.show(s.jobs_per_robot)}"
end
