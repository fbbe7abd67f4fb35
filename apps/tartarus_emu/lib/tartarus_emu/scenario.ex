defmodule TartarusEmu.Scenario do
  @moduledoc """
  One way to write an experiment: a behaviour for the scenario and a runner that seeds it,
  steps it, shows progress and writes its results.

  ## Writing a scenario

      defmodule MyScenario do
        @behaviour TartarusEmu.Scenario

        @impl true
        def name, do: "my_scenario"

        @impl true
        def setup(opts), do: {:ok, %{rng: opts.rng, series: TartarusTools.Series.new(), x: 0}}

        @impl true
        def step(state, step) do
          {dx, rng} = :rand.uniform_s(6, state.rng)
          x = state.x + dx
          %{state | rng: rng, x: x, series: TartarusTools.Series.record(state.series, :x, step, x)}
        end

        @impl true
        def done?(state, _step), do: state.x > 100

        @impl true
        def series(state), do: state.series

        @impl true
        def summary(state), do: %{x: state.x}
      end

      {:ok, result} = TartarusEmu.Scenario.run(MyScenario, seed: 7, steps: 50, out: "results/x")

  ## What the runner does

    1. picks the seed (`:seed`, else a random one, recorded in the summary) and passes
       `opts.rng`, an `:exsss` state made from it: a scenario draws all its randomness from
       `opts.rng` (or from `opts.seed`, e.g. agents' `seed:` options), so a run is
       reproducible;
    2. calls `c:setup/1` with the options as a map (`:seed`, `:rng`, `:steps` and whatever
       the caller passed);
    3. calls `c:step/2` for steps `1..steps`, stopping early when `c:done?/2` is true, with a
       progress line on standard error (`TartarusTools.Progress`, hidden when not a terminal
       or with `quiet: true`);
    4. writes into `:out` (default `TartarusTools.Report.default_out_dir/1`; `out: false`
       writes nothing): `series.csv` (every series, one column each), one CSV and one SVG
       line chart per series, the scenario's `c:charts/1`, `summary.json` and `summary.md`
       (with the `c:comparisons/1` rows), plus whatever `c:write/2` writes (before teardown, so it may read live processes);
    5. calls `c:teardown/1`, also when a step raises.

  The summary gets the runner's keys `scenario`, `seed`, `steps` (steps run), `setup_ms`
  and `run_ms` unless the scenario sets them itself.
  """

  alias TartarusTools.{Progress, Report, Series, SVG}
  alias Tartarus.Clock

  @typedoc "A scenario's state (anything)."
  @type state :: term()

  @typedoc """
  An extra chart: `file` (without `.svg`), `title`, `series` (names of series to draw
  together) and optional `x_label`, `y_label`, `labels` (legend names of the series, by
  series name, instead of the raw keys) and the `TartarusTools.SVG.line_chart/2` options
  `subtitle`, `note`, `x_unit`, `y_unit`, `y_min`, `y_max`, `references` (an ideal line,
  the thesis's numbers) and `x_integer`.
  """
  @type chart :: %{
          required(:file) => String.t(),
          required(:title) => String.t(),
          required(:series) => [Series.name()],
          optional(:x_label) => String.t(),
          optional(:y_label) => String.t(),
          optional(:labels) => %{Series.name() => String.t()},
          optional(atom()) => term()
        }

  @typedoc "What `run/2` returns."
  @type result :: %{summary: map(), series: Series.t(), out: Path.t() | nil, files: [Path.t()]}

  @doc "A plain name (letters, digits, `_ - .`), used for the default output directory."
  @callback name() :: String.t()

  @doc "Sets the scenario up. `opts` has `:seed`, `:rng`, `:steps` and the caller's options."
  @callback setup(opts :: map()) :: {:ok, state()} | {:error, term()}

  @doc "Runs step `step` (1-based)."
  @callback step(state(), step :: pos_integer()) :: state()

  @doc "True to stop after step `step` (optional; default: run all steps)."
  @callback done?(state(), step :: pos_integer()) :: boolean()

  @doc "The series recorded so far."
  @callback series(state()) :: Series.t()

  @doc "The summary: a JSON-encodable map."
  @callback summary(state()) :: map()

  @doc "Extra charts (optional)."
  @callback charts(state()) :: [chart()]

  @doc """
  The run's parameters and seed in a line (optional): the subtitle of every chart the
  runner draws (the per-series charts, and `charts/1` entries without their own).
  """
  @callback subtitle(state()) :: String.t()

  @doc """
  Rows "ours vs the thesis" for `summary.md` (optional; see
  `TartarusTools.Report.write_summary!/3`).
  """
  @callback comparisons(state()) :: [TartarusTools.Report.comparison()]

  @doc "The title of `summary.md` (optional; default `c:name/0`)."
  @callback title() :: String.t()

  @doc "Writes extra files into `dir` before teardown; returns their paths (optional)."
  @callback write(state(), dir :: Path.t()) :: [Path.t()]

  @doc "Stops what setup started (optional)."
  @callback teardown(state()) :: any()

  @doc """
  Panels the web dashboard shows for this scenario (optional; see
  `TartarusDashboard.Panel`), given the state after setup.
  """
  @callback panels(state()) :: [{module(), term()}]

  @doc """
  The emulated network the web dashboard shows (optional; default: the state's `:net`
  when it is a `TartarusEmu.Network`), or a function returning the one to show now, for a
  scenario that starts a new network at each step (see `TartarusEmu.Dashboard`).
  """
  @callback network(state()) :: TartarusEmu.Dashboard.source() | nil

  @optional_callbacks done?: 2,
                      charts: 1,
                      subtitle: 1,
                      comparisons: 1,
                      title: 0,
                      write: 2,
                      teardown: 1,
                      panels: 1,
                      network: 1

  @schema [
    seed: [type: :integer, doc: "seed of all randomness (default: a random one)"],
    steps: [type: :pos_integer, default: 100, doc: "steps to run at most"],
    out: [type: :any, doc: "output directory, or `false` for none"],
    quiet: [type: :boolean, default: false, doc: "no progress line"],
    progress_device: [
      type: :any,
      default: :standard_error,
      doc: "where progress goes (`false`: no progress line, even with `--progress`)"
    ],
    dashboard: [
      type: :any,
      doc:
        "serve the web dashboard on this port while the scenario runs (when its state " <>
          "keeps its network under `:net` or it defines `c:network/1`; see " <>
          "`TartarusEmu.Dashboard`), or dashboard options"
    ],
    step_ms: [type: :non_neg_integer, default: 0, doc: "pause after each step (to watch a run)"],
    time: [
      type: {:in, [:real, :virtual]},
      default: :real,
      doc:
        "the run's clock: `:real`, or `:virtual` (`Tartarus.Clock.Virtual`, seeded with the " <>
          "run's seed: CPU time is no time, the same seed gives the same run; one VM only)"
    ]
  ]

  @doc """
  Runs a scenario. Runner options (the others are passed to `c:setup/1`):

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, %{summary:, series:, out:, files:}}`, or `{:error, reason}` from setup or
  from a dashboard that could not start (what setup started is then stopped).
  """
  @spec run(module(), keyword()) :: {:ok, result()} | {:error, term()}
  def run(module, opts \\ []) do
    {runner, rest} = Keyword.split(opts, Keyword.keys(@schema))

    with {:ok, runner} <-
           Tartarus.Options.validate(runner, @schema, "TartarusEmu.Scenario.run/2") do
      Code.ensure_loaded(module)
      seed = runner[:seed] || :rand.uniform(1_000_000_000)
      steps = runner[:steps]

      setup_opts =
        rest
        |> Map.new()
        |> Map.merge(%{seed: seed, rng: :rand.seed_s(:exsss, seed), steps: steps})

      Tartarus.Clock.Virtual.within(runner[:time], seed, fn ->
        run(module, setup_opts, seed, runner)
      end)
    end
  end

  defp run(module, setup_opts, seed, runner) do
    t0 = Clock.machine_time(:millisecond)

    with {:ok, state} <- module.setup(setup_opts),
         {:ok, dash} <- dashboard(module, state, runner) do
      try do
        t1 = Clock.machine_time(:millisecond)
        {state, ran} = loop(module, state, setup_opts.steps, runner)
        t2 = Clock.machine_time(:millisecond)

        runner_keys = %{
          scenario: module.name(),
          seed: seed,
          steps: ran,
          setup_ms: t1 - t0,
          run_ms: t2 - t1,
          time: runner[:time]
        }

        summary = Map.merge(runner_keys, module.summary(state))
        series = module.series(state)
        {dir, files} = write(module, state, runner[:out], summary, series)
        {:ok, %{summary: summary, series: series, out: dir, files: files}}
      after
        if dash, do: TartarusDashboard.stop(dash)
        teardown(module, state)
      end
    end
  end

  # {:ok, dashboard or nil}; a dashboard that cannot start (a bad option, a port in use)
  # ends the run before it starts, with what setup started stopped.
  defp dashboard(module, state, runner) do
    with spec when spec != nil <- runner[:dashboard],
         net when is_struct(net, TartarusEmu.Network) or is_function(net, 0) <-
           network(module, state) do
      panels = if function_exported?(module, :panels, 1), do: module.panels(state), else: []

      with {:error, _} = error <-
             TartarusEmu.Dashboard.serve(
               net,
               spec,
               panels,
               runner[:progress_device] || :standard_error
             ) do
        teardown(module, state)
        error
      end
    else
      _ -> {:ok, nil}
    end
  end

  defp teardown(module, state),
    do: if(function_exported?(module, :teardown, 1), do: module.teardown(state))

  defp network(module, state) do
    cond do
      function_exported?(module, :network, 1) -> module.network(state)
      is_map(state) -> Map.get(state, :net)
      true -> nil
    end
  end

  defp loop(module, state, steps, runner) do
    progress =
      Progress.new(steps,
        label: module.name(),
        quiet: runner[:quiet],
        device: runner[:progress_device]
      )

    done? = function_exported?(module, :done?, 2)

    {state, ran, progress} =
      Enum.reduce_while(1..steps, {state, 0, progress}, fn step, {state, _, progress} ->
        state = module.step(state, step)
        if runner[:step_ms] > 0, do: Clock.sleep(runner[:step_ms])
        progress = Progress.advance(progress)

        if done? and module.done?(state, step),
          do: {:halt, {state, step, progress}},
          else: {:cont, {state, step, progress}}
      end)

    Progress.finish(progress)
    {state, ran}
  end

  # What a `charts/1` entry may pass to `SVG.line_chart/2` besides its title and labels.
  @chart_options [:subtitle, :note, :x_unit, :y_unit, :y_min, :y_max, :references, :x_integer]

  defp write(_module, _state, false, _summary, _series), do: {nil, []}

  defp write(module, state, out, summary, series) do
    dir = out || Report.default_out_dir(module.name())
    File.mkdir_p!(dir)

    subtitle = if function_exported?(module, :subtitle, 1), do: module.subtitle(state)
    csvs_and_charts = write_series(dir, module.name(), series, subtitle: subtitle)

    extra_charts =
      if function_exported?(module, :charts, 1) do
        all = Map.new(Series.to_chart(series), &{&1.name, &1})

        Enum.map(module.charts(state), fn c ->
          labels = Map.get(c, :labels, %{})

          lines =
            for name <- c.series,
                line = all[to_string(name)],
                do: %{line | name: Map.get(labels, name, line.name)}

          svg =
            SVG.line_chart(
              lines,
              [
                title: c.title,
                x_label: Map.get(c, :x_label, "step"),
                y_label: Map.get(c, :y_label, "")
              ] ++ Keyword.new(Map.take(Map.put_new(c, :subtitle, subtitle), @chart_options))
            )

          SVG.write!(Path.join(dir, "#{c.file}.svg"), svg)
        end)
      else
        []
      end

    extra = if function_exported?(module, :write, 2), do: module.write(state, dir), else: []

    comparisons =
      if function_exported?(module, :comparisons, 1), do: module.comparisons(state), else: []

    summaries =
      Report.write_summary!(dir, summary,
        title: if(function_exported?(module, :title, 0), do: module.title(), else: module.name()),
        comparisons: comparisons
      )

    # a chart of charts/1 may redraw a per-series chart under its name (a better title, units)
    {dir, Enum.uniq(csvs_and_charts ++ extra_charts ++ extra ++ summaries)}
  end

  @doc """
  Writes a run's series into `dir` as the runner does: `series.csv` (every series, one
  column each), and per series a CSV (`step`, value) and an SVG line chart titled
  `"<name>: <series>"`, with `opts[:subtitle]` under it (the run's parameters and seed).
  Returns the paths written. For an experiment that builds its series itself (a
  `TartarusEmu.Sweep` whose points are runs).
  """
  @spec write_series(Path.t(), String.t(), Series.t(), keyword()) :: [Path.t()]
  def write_series(dir, name, series, opts \\ []) do
    File.mkdir_p!(dir)

    csvs =
      [Report.write_csv!(dir, "series", Series.header(series), Series.to_rows(series))] ++
        Enum.map(Series.names(series), fn s ->
          Report.write_csv!(dir, to_string(s), ["step", to_string(s)], rows(series, s))
        end)

    charts =
      Enum.map(Series.to_chart(series), fn chart ->
        svg =
          SVG.line_chart([chart],
            title: "#{name}: #{chart.name}",
            subtitle: opts[:subtitle],
            x_label: "step",
            y_label: chart.name,
            y_min: if(Enum.all?(chart.points, fn {_, y} -> y >= 0 end), do: 0)
          )

        SVG.write!(Path.join(dir, "#{chart.name}.svg"), svg)
      end)

    csvs ++ charts
  end

  defp rows(series, name), do: Enum.map(Series.points(series, name), fn {s, v} -> [s, v] end)
end
