defmodule TartarusWarehouse.Experiment.Scaling do
  @moduledoc """
  `mix tartarus.warehouse --experiment scaling` (thesis §4.7.2, Fig. 4.4): point n runs
  `scaling_jobs` jobs of n soft tasks (Sort, Merge, Add, Sub, Div repeating; n = 5, 10,
  20, ... up to `max_tasks`) with equal durations on a network of `nodes` nodes
  (`scaling_robots` robots, the rest secondary), with task agents (searching blind, as in
  the thesis, and guided by signal fields) and with the central server: the average time
  per task against tasks per job, and its least-squares slope. With `big_robots` > 0 the
  last point also runs 20 jobs of 5 soft tasks in 20 independent pipelines on that many
  robots, agents guided (`big_run` in the summary).
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusWarehouse.Experiment.Jobs

  @impl Experiment
  def kinds, do: [:agents, :central, :guided, :big]

  @impl Experiment
  def points(p) do
    case Enum.filter([5, 10, 20, 30, 40, 50, 60, 80, 100], &(&1 <= p.max_tasks)) do
      [] -> [p.max_tasks]
      list -> list
    end
  end

  @impl Experiment
  def runs(n, state) do
    p = state.p
    jobs = Jobs.soft_jobs(p.scaling_jobs, n, 2000)

    big =
      if p.big_robots > 0 and n == List.last(state.points) do
        big_jobs = big_jobs()

        [
          {:big,
           [
             robots: p.big_robots,
             jobs: big_jobs,
             scale: p.scale,
             guide: true,
             seed: state.seed,
             mode: p.mode,
             timeout_ms: p.timeout_ms
           ], %{}}
        ]
      else
        []
      end

    big ++
      for kind <- [:agents, :central, :guided] do
        {kind,
         [
           robots: p.scaling_robots,
           secondary: p.nodes - p.scaling_robots - 1,
           jobs: jobs,
           scale: p.scale,
           design: if(kind == :central, do: :central, else: :agents),
           guide: kind == :guided,
           seed: state.seed,
           mode: p.mode,
           latency_ms: p.latency_ms,
           server_ms: p.server_ms,
           timeout_ms: p.timeout_ms
         ], %{}}
      end
  end

  # 20 jobs of 5 soft tasks, job j's task i needing {:psi, i, j}: 20 independent pipelines.
  defp big_jobs do
    for j <- 1..20 do
      %{
        id: j,
        tasks:
          for {prog, i} <- Enum.with_index(TartarusWarehouse.Program.soft(5), 1) do
            %{
              name: "T#{i}",
              resources: [{:psi, i, j}],
              after: if(i > 1, do: ["T#{i - 1}"], else: []),
              program: prog
            }
          end
      }
    end
  end

  @impl Experiment
  def record(n, state) do
    [a, c, g] =
      Enum.filter(state.runs, &(&1.point == n and &1.kind in [:agents, :central, :guided]))

    per = fn r -> Float.round(r.makespan_ms / (length(r.jobs) * n), 3) end

    state.series
    |> Series.record(:avg_task_ms_agents, n, per.(a))
    |> Series.record(:avg_task_ms_central, n, per.(c))
    |> Series.record(:avg_task_ms_agents_guided, n, per.(g))
    |> Series.record(:migrations_agents_guided, n, g.migrations)
    |> Series.record(:migrations_agents, n, a.migrations)
  end

  @impl Experiment
  def charts(state),
    do: [
      %{
        file: "avg_task_time",
        title: "Average time per task: task agents vs central server (Fig. 4.4)",
        subtitle: "seed #{state.seed}",
        series: [:avg_task_ms_agents, :avg_task_ms_central, :avg_task_ms_agents_guided],
        labels: %{
          avg_task_ms_agents: "task agents",
          avg_task_ms_central: "central server",
          avg_task_ms_agents_guided: "task agents, guided"
        },
        x_label: "tasks per job",
        y_label: "time per task",
        y_unit: "ms",
        y_min: 0
      }
    ]

  @impl Experiment
  def summary(base, state) do
    p = state.p
    agents = Experiment.by(state, :avg_task_ms_agents)
    central = Experiment.by(state, :avg_task_ms_central)
    guided = Experiment.by(state, :avg_task_ms_agents_guided)

    Map.merge(base, %{
      big_run: big_run(Enum.find(state.runs, &(&1.kind == :big))),
      speedup: nil,
      avg_task_ms_agents: agents,
      avg_task_ms_central: central,
      avg_task_ms_agents_guided: guided,
      agents_faster_at:
        for({n, a} <- agents, a < central[n], do: String.to_integer(n)) |> Enum.sort(),
      slope_ms_per_task: %{
        agents: slope(agents),
        central: slope(central),
        agents_guided: slope(guided)
      },
      latency_ms: p.latency_ms,
      server_ms: p.server_ms,
      nodes: p.nodes,
      robots: p.scaling_robots,
      jobs_per_run: p.scaling_jobs
    })
  end

  defp big_run(nil), do: nil

  defp big_run(r) do
    %{
      robots: length(r.robots),
      jobs: length(r.jobs),
      completed_jobs: r.completed_jobs,
      mutex_violations: r.violations,
      wall_ms: r.wall_ms,
      makespan_ms: round(r.makespan_ms),
      migrations: r.migrations
    }
  end

  @doc """
  The least-squares slope of ms per task against tasks per job (keys are strings, as in
  the summary); nil for fewer than two points.

      iex> TartarusWarehouse.Experiment.Scaling.slope(%{"5" => 10.0, "10" => 12.0, "20" => 16.0})
      0.4
      iex> TartarusWarehouse.Experiment.Scaling.slope(%{"5" => 10.0})
      nil
  """
  @spec slope(%{String.t() => number()}) :: float() | nil
  def slope(points) when map_size(points) < 2, do: nil

  def slope(points) do
    xy = for {n, y} <- points, do: {String.to_integer(n) * 1.0, y * 1.0}
    mx = TartarusTools.Stats.mean(Enum.map(xy, &elem(&1, 0)))
    my = TartarusTools.Stats.mean(Enum.map(xy, &elem(&1, 1)))
    sxy = Enum.sum(for {x, y} <- xy, do: (x - mx) * (y - my))
    sxx = Enum.sum(for {x, _} <- xy, do: (x - mx) * (x - mx))
    Float.round(sxy / sxx, 4)
  end

  @impl Experiment
  def gantt(%{kind: :agents, point: n}, %{points: [n | _]}),
    do: {"#{n} tasks per job, agents", "gantt_#{n}_tasks.svg"}

  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s) do
    "avg ms per task, agents: #{TartarusTools.CLI.show(s.avg_task_ms_agents)}\navg ms per task, central: #{TartarusTools.CLI.show(s.avg_task_ms_central)}"
  end
end
