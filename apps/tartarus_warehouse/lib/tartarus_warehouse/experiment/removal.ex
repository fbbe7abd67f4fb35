defmodule TartarusWarehouse.Experiment.Removal do
  @moduledoc """
  `mix tartarus.warehouse --experiment removal` (thesis Fig. 4.13): 10 warehouse jobs on 3
  robots; robot r2's battery runs low once 2 jobs completed (it finishes its job and
  leaves), and a fourth robot joins once 6 jobs completed (beyond the thesis's figure), on `--seeds` seeds (seed, seed
  + 1, ...: the sweep's seeds, one arm). Per seed: the jobs each robot ran, each job's
  span, each robot's utilisation before r2 left (up to its last task's end), between (up
  to r4's joining) and after, the jobs r2 began after its retirement was asked, and a
  Gantt chart.
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusWarehouse.Experiment.Jobs

  @impl Experiment
  def kinds, do: [:variable]

  @impl Experiment
  def points(p), do: Experiment.seeds(p)

  @impl Experiment
  def sweep(state), do: Experiment.seed_sweep("removal", state)

  @impl Experiment
  def runs(seed, state) do
    opts = [
      robots: 4,
      standby: [4],
      jobs: Jobs.thesis_jobs(10, 2000),
      jitter: state.p.jitter,
      latency_ms: state.p.latency_ms,
      events: [{2, {:retire, 2}}, {6, {:join, 4}}]
    ]

    [{:variable, Experiment.floor(state, seed) ++ opts, %{run_seed: seed}}]
  end

  @impl Experiment
  def record(seed, state) do
    r = Enum.find(state.runs, &(&1.point == seed))
    Series.record(state.series, :mean_busy_robots, seed, r.occupancy.mean)
  end

  @doc """
  The phases of a removal run, µs: `t0` (the first submission), `retire_at` (the
  retirement asked), `left` (r2's last task's end), `join_at` (r4's joining) and `end`
  (the last task's end); and each robot's utilisation `before` (t0 to left), `between`
  (left to join_at) and `after` (join_at to end), and the jobs r2 began after
  `retire_at`.
  """
  @spec phases(map()) :: map()
  def phases(r) do
    at = fn event ->
      Enum.find_value(r.changes, fn c -> if c.event == event, do: c.at_us end)
    end

    r2 = Enum.filter(r.history, &(&1.robot == "r2"))
    retire_at = at.({:retire, 2})
    join_at = at.({:join, 4})
    left = r2 |> Enum.map(& &1.stop_us) |> Enum.max(fn -> r.t0_us end)
    last = r.history |> Enum.map(& &1.stop_us) |> Enum.max()
    u = &Experiment.utilisation(r.history, r.robots, &1)
    # a job r2 began (its first task on r2) after the retirement was asked
    first_on_r2 =
      r2 |> Enum.group_by(& &1.job, & &1.start_us) |> Map.new(fn {j, s} -> {j, Enum.min(s)} end)

    %{
      t0: r.t0_us,
      retire_at: retire_at,
      left: left,
      join_at: join_at,
      end: last,
      before: u.({r.t0_us, left}),
      between: u.({left, join_at || last}),
      after: if(join_at, do: u.({join_at, last}), else: %{}),
      r2_jobs_after_retire:
        for({j, s} <- first_on_r2, retire_at != nil and s > retire_at, do: j) |> Enum.sort()
    }
  end

  @impl Experiment
  def summary(base, state) do
    by_seed = fn f -> Map.new(state.runs, &{to_string(&1.run_seed), f.(&1)}) end
    ms = fn us, r -> us && Float.round((us - r.t0_us) / 1000, 3) end

    jobs_of = fn r, robot ->
      r.history
      |> Enum.filter(&(&1.robot == robot))
      |> Enum.map(& &1.job)
      |> Enum.uniq()
      |> Enum.sort()
    end

    phases = Map.new(state.runs, &{&1.run_seed, phases(&1)})

    Map.merge(base, %{
      speedup: nil,
      removed_robot: "r2",
      joined_robot: "r4",
      seeds: Enum.map(state.runs, & &1.run_seed),
      jobs_per_robot: by_seed.(fn r -> Map.new(r.robots, &{&1, jobs_of.(r, &1)}) end),
      job_span_ms:
        by_seed.(fn r ->
          Map.new(Experiment.job_spans(r.history), &{to_string(elem(&1, 0)), elem(&1, 1)})
        end),
      phase_ms:
        by_seed.(fn r ->
          p = phases[r.run_seed]
          Map.new([:retire_at, :left, :join_at, :end], &{&1, ms.(p[&1], r)})
        end),
      utilisation_before: by_seed.(&phases[&1.run_seed].before),
      utilisation_between: by_seed.(&phases[&1.run_seed].between),
      utilisation_after: by_seed.(&phases[&1.run_seed].after),
      r2_jobs_after_retire: by_seed.(&phases[&1.run_seed].r2_jobs_after_retire),
      mean_busy_robots: by_seed.(& &1.occupancy.mean)
    })
  end

  @impl Experiment
  def gantt(%{kind: :variable, run_seed: seed}, _state),
    do:
      {"r2 leaves after 2 jobs, r4 joins after 6 (Fig. 4.13), seed #{seed}",
       "gantt_removal_seed_#{seed}.svg"}

  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s),
    do:
      "jobs per robot, by seed: #{TartarusTools.CLI.show(s.jobs_per_robot)}\nutilisation before / between / after: #{TartarusTools.CLI.show(s.utilisation_before)} / #{TartarusTools.CLI.show(s.utilisation_between)} / #{TartarusTools.CLI.show(s.utilisation_after)}"
end
