defmodule TartarusWarehouse.Demo do
  @moduledoc false
  # The warehouse's part of `mix tartarus.demo`: 8 jobs of T1-T4 on 1 and 4 robots.
  @behaviour TartarusTools.Demo
  import TartarusTools.Demo, only: [say: 1]

  @impl true
  def title, do: "Warehouse: robots line up into a clock-less pipeline of task agents"

  @impl true
  def run(opts) do
    jobs = TartarusWarehouse.Experiment.Jobs.thesis_jobs(8, 2000)

    runs =
      for k <- [1, 4] do
        {:ok, r} =
          TartarusWarehouse.Floor.run(robots: k, jobs: jobs, scale: 0.01, seed: opts[:seed] || 1)

        {k, r}
      end

    [{1, one}, {4, four}] = runs
    v = TartarusWarehouse.Checker.violations(four.history)

    say(
      "8 jobs of 4 tasks (2 s each, run as 20 ms): 1 robot #{round(one.makespan_ms)} ms, 4 robots #{round(four.makespan_ms)} ms"
    )

    say(
      "speed-up #{Float.round(one.makespan_ms / four.makespan_ms, 2)}; mutual-exclusion violations: #{length(v)}; task agents made #{four.migrations} migrations"
    )

    :ok
  end
end
