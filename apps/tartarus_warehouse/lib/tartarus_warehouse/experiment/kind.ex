defmodule TartarusWarehouse.Experiment.Kind do
  @moduledoc """
  What one warehouse experiment is (`TartarusWarehouse.Experiment` runs them, by name):
  the behaviour its module implements (`use TartarusWarehouse.Experiment.Kind` gives the
  defaults), and the helpers the experiments share.
  """

  import Kernel, except: [floor: 1]

  alias TartarusTools.Series

  @typedoc """
  What an experiment's callbacks see: `p` (the options, a map), `seed`, `points`, `runs`
  (every floor run so far, in order: `TartarusWarehouse.Floor.run/1`'s result with
  `violations`, `completed_jobs`, `occupancy`, and the run's `kind`, `point`, `specs`
  and whatever its declaration added), `series`.
  """
  @type state :: map()

  @typedoc """
  A floor to run: its kind (how the experiment names it: `:variable`, `:equal`,
  `:agents`, ...), the options of `TartarusWarehouse.Floor.run/1`, and keys to add to its
  run (e.g. `run_seed`).
  """
  @type floor_run :: {atom(), keyword(), map()}

  @doc "The points of the experiment (one scenario step each), from the options."
  @callback points(p :: map()) :: [term()]

  @doc "The floors point `point` runs, in order."
  @callback runs(point :: term(), state()) :: [floor_run()]

  @doc "The series after point `point` ran (its runs are in `state.runs`)."
  @callback record(point :: term(), state()) :: Series.t()

  @doc "The charts of the series (see `c:TartarusEmu.Scenario.charts/1`)."
  @callback charts(state()) :: [map()]

  @doc "The experiment's summary keys, merged over the keys every experiment has (`base`)."
  @callback summary(base :: map(), state()) :: map()

  @doc "The comparisons with the thesis (see `c:TartarusEmu.Scenario.comparisons/1`)."
  @callback comparisons(state()) :: [map()]

  @doc "For a run to draw as a Gantt chart: `{what, file}`; nil for none."
  @callback gantt(run :: map(), state()) :: {String.t(), String.t()} | nil

  @doc "The lines `mix tartarus.warehouse` prints for the summary."
  @callback text(summary :: map()) :: String.t()

  @doc "The kinds of floor the experiment runs (each one's makespan is a sweep metric)."
  @callback kinds() :: [atom()]

  @doc """
  The experiment's sweep, when its arms are not its points on the run's seed: `arms`
  (`[{name, opts}]`), `seeds`, and `point`, a function of an arm's opts and a seed that
  gives the point to run.
  """
  @callback sweep(state()) :: %{
              arms: [{String.t(), term()}],
              seeds: [integer()],
              point: (term(), integer() -> term())
            }

  @optional_callbacks sweep: 1

  @doc """
  Makes a module an experiment (`@behaviour TartarusWarehouse.Experiment.Kind`) with defaults
  it may override: one point (`[1]`), no charts, no comparisons, and for its one floor the
  series `mean_busy_robots` (Eq. 4.2).
  """
  defmacro __using__(_opts) do
    quote do
      @behaviour TartarusWarehouse.Experiment.Kind

      alias TartarusTools.Series
      alias TartarusWarehouse.Experiment.Kind, as: Experiment

      @impl Experiment
      def points(_p), do: [1]

      @impl Experiment
      def charts(_state), do: []

      @impl Experiment
      def comparisons(_state), do: []

      @impl Experiment
      def record(_point, %{runs: [r]} = state),
        do: Series.record(state.series, :mean_busy_robots, 1, r.occupancy.mean)

      defoverridable points: 1, charts: 1, comparisons: 1, record: 2
    end
  end

  @doc """
  A series of the state as a summary object: x (as a string) => y.

      iex> series = TartarusTools.Series.new() |> TartarusTools.Series.record(:speedup, 2, 1.5)
      iex> TartarusWarehouse.Experiment.Kind.by(%{series: series}, :speedup)
      %{"2" => 1.5}
  """
  @spec by(map(), atom()) :: %{String.t() => term()}
  def by(state, name),
    do: Map.new(Series.points(state.series, name), fn {x, y} -> {to_string(x), y} end)

  @doc """
  The span of executions, `{first start, last stop}` in µs.

      iex> TartarusWarehouse.Experiment.Kind.span([%{start_us: 5, stop_us: 9}, %{start_us: 2, stop_us: 7}])
      {2, 9}
  """
  @spec span([map()]) :: {integer(), integer()}
  def span(entries),
    do:
      {entries |> Enum.map(& &1.start_us) |> Enum.min(),
       entries |> Enum.map(& &1.stop_us) |> Enum.max()}

  @doc """
  The options every floor of an experiment shares: the run's `scale`, `seed`, `mode` and
  `timeout_ms`.

      iex> TartarusWarehouse.Experiment.Kind.floor(%{seed: 3, p: %{scale: 0.01, mode: :virtual, timeout_ms: 9}})
      [scale: 0.01, seed: 3, mode: :virtual, timeout_ms: 9]
  """
  @spec floor(state()) :: keyword()
  def floor(state),
    do: [
      scale: state.p.scale,
      seed: state.seed,
      mode: state.p.mode,
      timeout_ms: state.p.timeout_ms
    ]

  @doc """
  The time scale applied to a time of the thesis's scale 0.01: `ms * scale / 0.01`,
  rounded (the experiments' event times are written at the default scale).

      iex> TartarusWarehouse.Experiment.Kind.scaled(45, %{scale: 0.02})
      90
  """
  @spec scaled(number(), map()) :: integer()
  def scaled(ms, p), do: round(ms * p.scale / 0.01)

  @doc """
  The seeds of an experiment run on `--seeds` seeds: seed, seed + 1, ...

      iex> TartarusWarehouse.Experiment.Kind.seeds(%{seed: 7, seeds: 3})
      [7, 8, 9]
  """
  @spec seeds(map()) :: [integer()]
  def seeds(p), do: Enum.to_list(p.seed..(p.seed + p.seeds - 1))

  @doc """
  The sweep of an experiment whose points are its seeds (`seeds/1`): one arm named
  `name`, the points as the sweep's seeds, each run's point its seed.
  """
  @spec seed_sweep(String.t(), state()) :: map()
  def seed_sweep(name, state),
    do: %{arms: [{name, nil}], seeds: state.points, point: fn nil, seed -> seed end}

  @doc """
  The floor options of `floor/1` on the seed `seed` (a point that is a seed).
  """
  @spec floor(state(), integer()) :: keyword()
  def floor(state, seed), do: floor(%{state | seed: seed})

  @doc """
  Each job's span, ms: its first task's start to its last task's stop (tasks skipped
  left out), keyed by job id.

      iex> h = [%{job: 1, start_us: 0, stop_us: 2_000, skipped: false},
      ...>      %{job: 1, start_us: 1_000, stop_us: 5_000, skipped: false}]
      iex> TartarusWarehouse.Experiment.Kind.job_spans(h)
      %{1 => 5.0}
  """
  @spec job_spans([map()]) :: %{term() => float()}
  def job_spans(history) do
    history
    |> Enum.reject(& &1.skipped)
    |> Enum.group_by(& &1.job)
    |> Map.new(fn {job, es} ->
      {a, b} = span(es)
      {job, Float.round((b - a) / 1000, 3)}
    end)
  end

  @doc """
  Each robot's utilisation in the window `{from_us, to_us}`: the fraction of it during
  which the robot ran a task (executions clipped to the window), keyed by robot; nil for
  an empty window.

      iex> h = [%{robot: "r1", start_us: 0, stop_us: 50}, %{robot: "r2", start_us: 80, stop_us: 200}]
      iex> TartarusWarehouse.Experiment.Kind.utilisation(h, ["r1", "r2", "r3"], {0, 100})
      %{"r1" => 0.5, "r2" => 0.2, "r3" => 0.0}
  """
  @spec utilisation([map()], [String.t()], {integer(), integer()}) :: %{
          String.t() => float() | nil
        }
  def utilisation(history, robots, {from, to}) do
    Map.new(robots, fn robot ->
      busy =
        for %{robot: ^robot} = e <- history,
            do: max(min(e.stop_us, to) - max(e.start_us, from), 0)

      {robot, if(to > from, do: Float.round(Enum.sum(busy) / (to - from), 3))}
    end)
  end

  @doc """
  The most executions running at one instant.

      iex> h = [%{start_us: 0, stop_us: 10}, %{start_us: 5, stop_us: 20}, %{start_us: 10, stop_us: 30}]
      iex> TartarusWarehouse.Experiment.Kind.peak_concurrency(h)
      2
  """
  @spec peak_concurrency([map()]) :: non_neg_integer()
  def peak_concurrency(history) do
    history
    |> Enum.flat_map(&[{&1.start_us, 1}, {&1.stop_us, -1}])
    # at one instant a stop comes before a start
    |> Enum.sort()
    |> Enum.map_reduce(0, fn {_, d}, n -> {n + d, n + d} end)
    |> elem(0)
    |> Enum.max(fn -> 0 end)
  end
end
