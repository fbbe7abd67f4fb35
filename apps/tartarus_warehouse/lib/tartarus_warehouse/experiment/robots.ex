defmodule TartarusWarehouse.Experiment.Robots do
  @moduledoc """
  `mix tartarus.warehouse --experiment robots` (thesis §4.7.4, Figs. 4.7-4.10): point k
  runs the thesis's warehouse jobs (T1-T4) on k robots (k = 1..`robots`): `jobs` jobs with
  variable durations (each robot its own pace, each execution a spread of `jitter`), then
  `equal_jobs` jobs with equal durations. Series: the speed-up over one robot of both, the
  makespans, the mean busy robots; compared with the thesis's speed-ups (1.75, 1.84, 2.21
  on 2, 3, 4 robots).
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusWarehouse.Experiment.Jobs

  @thesis_speedup %{2 => 1.75, 3 => 1.84, 4 => 2.21}

  @impl Experiment
  def kinds, do: [:variable, :equal]

  @impl Experiment
  def points(p), do: Enum.to_list(1..p.robots)

  @impl Experiment
  def runs(k, state) do
    p = state.p
    paces = Enum.map(1..k, &(1.0 + 0.1 * rem(&1 * 7, 5)))
    floor = [robots: k] ++ Experiment.floor(state)

    [
      {:variable, floor ++ [jobs: Jobs.thesis_jobs(p.jobs, 2000), jitter: p.jitter, paces: paces],
       %{}},
      {:equal, floor ++ [jobs: Jobs.thesis_jobs(p.equal_jobs, 2000)], %{}}
    ]
  end

  @impl Experiment
  def record(k, state) do
    [v, e] = Enum.filter(state.runs, &(&1.point == k))
    [v1, e1] = Enum.filter(state.runs, &(&1.point == 1))

    state.series
    |> Series.record(:speedup_variable, k, Float.round(v1.makespan_ms / v.makespan_ms, 3))
    |> Series.record(:speedup_equal, k, Float.round(e1.makespan_ms / e.makespan_ms, 3))
    |> Series.record(:makespan_variable_ms, k, round(v.makespan_ms))
    |> Series.record(:makespan_equal_ms, k, round(e.makespan_ms))
    |> Series.record(:mean_busy_robots_equal, k, e.occupancy.mean)
  end

  @impl Experiment
  def charts(state) do
    p = state.p

    [
      %{
        file: "speedup",
        title: "Speed-up over one robot (Figs. 4.7-4.10)",
        subtitle:
          "#{p.jobs} jobs of variable durations (jitter #{p.jitter}), #{p.equal_jobs} of equal " <>
            "durations, 1-#{p.robots} robots, seed #{state.seed}",
        series: [:speedup_variable, :speedup_equal],
        labels: %{
          speedup_variable: "ours, variable durations",
          speedup_equal: "ours, equal durations"
        },
        references: [
          %{name: "ideal (k robots: k)", points: [{1, 1}, {max(p.robots, 2), max(p.robots, 2)}]},
          %{
            name: "thesis (§4.7.4)",
            points: Enum.sort(@thesis_speedup),
            style: :points
          }
        ],
        x_label: "robots",
        y_label: "speed-up",
        y_unit: "makespan on 1 robot / on k",
        y_min: 0
      }
    ]
  end

  @impl Experiment
  def summary(base, state) do
    p = state.p

    Map.merge(base, %{
      speedup: Experiment.by(state, :speedup_variable),
      speedup_equal: Experiment.by(state, :speedup_equal),
      makespan_variable_ms: Experiment.by(state, :makespan_variable_ms),
      makespan_equal_ms: Experiment.by(state, :makespan_equal_ms),
      jobs_variable: p.jobs,
      jobs_equal: p.equal_jobs,
      jitter: p.jitter,
      speedup_thesis: Map.new(@thesis_speedup, fn {k, v} -> {to_string(k), v} end)
    })
  end

  @impl Experiment
  def comparisons(state) do
    ours = Map.new(Series.points(state.series, :speedup_variable))

    for {k, thesis} <- Enum.sort(@thesis_speedup), Map.has_key?(ours, k) do
      %{metric: "speed-up on #{k} robots (variable durations)", ours: ours[k], thesis: thesis}
    end
  end

  @impl Experiment
  def gantt(%{kind: :variable, point: k}, _state),
    do: {"#{k} robot(s), variable durations", "gantt_#{k}_robots.svg"}

  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s) do
    "speed-up (variable durations): #{TartarusTools.CLI.show(s.speedup)}; thesis #{TartarusTools.CLI.show(s.speedup_thesis)}\n" <>
      "speed-up (equal durations, #{s.jobs_equal} jobs): #{TartarusTools.CLI.show(s.speedup_equal)}"
  end
end
