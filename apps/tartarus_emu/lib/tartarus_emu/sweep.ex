defmodule TartarusEmu.Sweep do
  @opts_schema [
    out: [type: :any, doc: "output directory, or `false` for none"],
    quiet: [
      type: :boolean,
      default: false,
      doc: "no line per run (the standard devices get them only when they are a terminal)"
    ],
    progress_device: [type: :any, default: :standard_error, doc: "where the lines go"],
    concurrency: [type: :pos_integer, doc: "runs at a time (overrides the spec's)"],
    time: [
      type: {:in, [:real, :virtual]},
      default: :real,
      doc:
        "each run's clock: `:real`, or `:virtual` (each run in `Tartarus.Clock.Virtual` " <>
          "seeded with its seed, one run at a time: the VM has one clock)"
    ],
    fresh_vm: [
      type: :boolean,
      default: true,
      doc:
        "in virtual time, each run in a fresh VM of its own (`TartarusEmu.FreshVM`) when " <>
          "its function can be loaded there; a run record says where it ran (`vm: :fresh | :this`)"
    ]
  ]

  @moduledoc """
  The level above a run: a **sweep** runs every (arm, seed) of an experiment, collects each
  run's summary, aggregates them per arm, tests arms against each other and writes the
  files. One run is one `TartarusEmu.Scenario` run (or any function returning a summary);
  a sweep is many of them.

  ## A complete example

      spec = %{
        name: "walk",
        title: "Random walk: a long stride against a short one",
        # arms: named option sets, in the order they are reported
        arms: [{"long", [stride: 6]}, {"short", [stride: 2]}],
        seeds: 1..10,
        # one run: the arm (%{name:, opts:}) and the seed -> the run's summary map
        run: fn arm, seed ->
          {:ok, r} =
            TartarusEmu.Scenario.run(MyWalk, [seed: seed, out: false, quiet: true] ++ arm.opts)

          r.summary
        end,
        # numbers aggregated per arm and box-plotted: a summary key or a function of it
        metrics: [steps: :steps, distance: fn s -> abs(s.x) end],
        # one-sided Mann-Whitney: "long" takes fewer steps than "short"
        tests: [{"long", :less, "short", :steps}]
      }

      {:ok, result} = TartarusEmu.Sweep.run(spec, out: "results/walk")
      result.summary.sweep.aggregates["long"].steps.median
      result.summary.sweep.tests |> hd() |> Map.fetch!(:p_value)

  `scenario:` is a shorter way to write the `run:` above: `scenario: MyWalk, base: [...]`
  runs `TartarusEmu.Scenario.run(MyWalk, base ++ arm.opts ++ [seed: seed, out: false])`
  (quiet unless `base` says otherwise) and keeps the summary, with the series as the run's
  `data`.

  ## The spec

    * `:name` - a plain name (default output directory `results/<name>-<time>`);
    * `:title` - the title of `summary.md` (default: the name);
    * `:subtitle` - the parameters the arms share (`"10 hosts (grid), 600 steps at most"`),
      put before the seeds under the box plots' titles;
    * `:arms` - `[{name, opts}]`: `name` a string, `opts` anything the run reads;
    * `:seeds` - the seeds (a list or a range);
    * `:run` - `fn arm, seed -> summary end`, where `arm` is `%{name:, opts:}`; it may return
      `{summary, data}` to keep `data` (anything: series, traces) in the run record for
      `:write` without writing it to the summary; or `:scenario` (and `:base`), above;
    * `:order` - `:seed_major` (default: every arm of the first seed, then the second
      seed, ...) or `:arm_major`: the order of the runs in the result and in `runs.csv`;
    * `:metrics` - `[{name, key | fun}]` or `[{name, key | fun, title}]`: numbers taken from
      each summary (`nil` when a run has none), described per arm (`TartarusTools.Stats.describe/1`: n, mean, sd, median,
      q1, q3, iqr, min, max) and drawn as a box plot `<metric>.svg` per metric when some
      arm has two runs or more (titled `title`);
    * `:tests` - `[{arm_a, :greater | :less, arm_b, metric}]`: one-sided Mann-Whitney U
      tests (`TartarusTools.Stats.mann_whitney/3`, exact up to 20 runs an arm) that the
      metric of `arm_a` tends to be greater (less) than that of `arm_b`; a fifth element,
      options of the test (`method: :exact`), is optional;
    * `:csv` - `{header, fn run -> [row] end}`: the rows of `runs.csv` for one run (default:
      `arm, seed` and the metrics, one row a run);
    * `:summary` - `fn result -> map end`: the experiment's own summary keys (`result` has
      `:runs`, `:aggregates`, `:tests`); the sweep adds its own under `:sweep`;
    * `:write` - `fn dir, result -> [path] end`: extra files (charts of one run, ...);
    * `:report` - `fn summary -> keyword end`: what `summary.json` and `summary.md` show,
      when it is not just the summary (`summary` is the full one, `:sweep` included):
      `summary:` the map written (default: the summary; e.g. without a bulky key that
      has a CSV of its own), `comparisons:` rows `%{metric:, ours:, thesis:}` of an
      "Ours vs thesis" table, `markdown:` the experiment's own tables after the key table
      (`TartarusTools.Report.write_summary!/3`). The returned summary is unchanged;
    * `:concurrency` - runs at a time (default: the schedulers online); 1 for runs that
      share something global (a dashboard, peer nodes, fixed host names).

  A run record is `%{arm:, opts:, seed:, summary:, data:, ms:, vm:}` (`vm`: `:fresh` for a run
  in a fresh VM of its own, `:this` otherwise; see the option `:fresh_vm`), plus in virtual time
  `clock: %{virtual_ms:, fired:, dirty_overlaps:}` (`Tartarus.Clock.Virtual.stats/0`); the
  summary's `sweep` then carries `replay: %{dirty_overlaps:, runs_with_overlaps:}`: 0 is the
  witness that no heap was collected on a dirty scheduler while another process could run,
  the one way known to make a run in virtual time differ when rerun with its seed.

  Each run goes in a process of its own, which ends with the run: what must outlive a run
  (a named ETS table used as a memo, a dashboard) is created by the caller before
  `run/2`.

  ## What `run/2` does

    1. runs every (arm, seed), `:concurrency` at a time, each in its own process. A run's
       numbers depend on its seed only: results are collected in the declared order,
       whatever order the runs finish in;
    2. prints a line per finished run on standard error (`walk [3/20] long seed 2 (1.4 s)
       elapsed 0:04  ETA 0:23`: what, k of n, elapsed, ETA), unless `quiet: true` or the
       device is standard error or output and not a terminal; a run that asked for
       progress (`TartarusTools.Progress.force/1`, a mix task's `--progress`) gets them
       in every case;
    3. describes every metric per arm and runs the tests;
    4. writes into `:out` (default `TartarusTools.Report.default_out_dir(name)`; `false`
       for nothing): `runs.csv`, `<metric>.svg` box plots, the spec's `:write` files,
       `summary.json` and `summary.md` (the spec's summary plus `sweep`: name, seeds, arms,
       runs, aggregates, tests; or what the spec's `:report` says).

  It returns `{:ok, %{summary:, runs:, aggregates:, tests:, out:, files:}}`: `summary` is
  JSON-encodable (what a mix task prints with `--json`).

  ## Options

  #{Tartarus.Options.docs(@opts_schema)}
  """

  alias TartarusTools.{Report, Stats, SVG}
  alias Tartarus.Clock

  @typedoc "One arm: a name and the options its runs read."
  @type arm :: %{name: String.t(), opts: term()}

  @typedoc "One finished run."
  @type run_record :: %{
          arm: String.t(),
          opts: term(),
          seed: integer(),
          summary: map(),
          data: term(),
          ms: non_neg_integer()
        }

  @typedoc "A test between two arms, as run and reported."
  @type test_result :: %{
          a: String.t(),
          alternative: :greater | :less,
          b: String.t(),
          metric: atom(),
          u: float(),
          p_value: float(),
          n1: non_neg_integer(),
          n2: non_neg_integer(),
          method: :exact | :normal
        }

  @typedoc "What `run/2` returns."
  @type result :: %{
          summary: map(),
          runs: [run_record()],
          aggregates: %{String.t() => %{atom() => Stats.description()}},
          tests: [test_result()],
          out: Path.t() | nil,
          files: [Path.t()]
        }

  @doc """
  Runs a sweep (see the module doc for the spec and the options). Returns
  `{:ok, result}` or `{:error, message}` for a bad spec or options.
  """
  @spec run(map() | keyword(), keyword()) :: {:ok, result()} | {:error, String.t()}
  def run(spec, opts \\ []) do
    with {:ok, spec} <- check_spec(Map.new(spec)),
         {:ok, o} <- Tartarus.Options.validate(opts, @opts_schema, "TartarusEmu.Sweep.run/2") do
      o = Map.new(o)
      runs = run_all(spec, o)
      aggregates = aggregate(runs, spec)
      tests = Enum.map(spec.tests, &test(&1, runs, spec))
      partial = %{runs: runs, aggregates: aggregates, tests: tests}

      summary =
        spec.summary.(partial)
        |> Map.put(
          :sweep,
          %{
            name: spec.name,
            seeds: spec.seeds,
            arms: Enum.map(spec.arms, & &1.name),
            runs: length(runs),
            aggregates: aggregates,
            tests: tests
          }
          |> Map.merge(replay(runs))
        )

      result = Map.merge(partial, %{summary: summary, out: nil, files: []})

      case Map.get(o, :out) do
        false ->
          {:ok, result}

        out ->
          dir = out || Report.default_out_dir(spec.name)
          {:ok, %{result | out: dir, files: write(dir, spec, result)}}
      end
    end
  end

  @doc """
  The rows of `runs` grouped by arm, in the arms' order: `[{arm, [run]}]`. For an
  experiment's own summary (`:summary` of the spec).

      iex> runs = [%{arm: "b", seed: 1}, %{arm: "a", seed: 1}, %{arm: "b", seed: 2}]
      iex> TartarusEmu.Sweep.by_arm(runs, ["b", "a"])
      [{"b", [%{arm: "b", seed: 1}, %{arm: "b", seed: 2}]}, {"a", [%{arm: "a", seed: 1}]}]
  """
  @spec by_arm([map()], [String.t()]) :: [{String.t(), [map()]}]
  def by_arm(runs, arm_names) do
    groups = Enum.group_by(runs, & &1.arm)
    for name <- arm_names, do: {name, Map.get(groups, name, [])}
  end

  # -- the spec ---------------------------------------------------------------------------

  defp check_spec(spec) do
    name = to_string(Map.get(spec, :name, ""))
    arms = Map.get(spec, :arms, [])
    seeds = Enum.to_list(Map.get(spec, :seeds, []))

    cond do
      not Regex.match?(~r/\A[A-Za-z0-9_.\-]+\z/, name) ->
        {:error, "Sweep: expected :name to be a plain name, got: #{inspect(spec[:name])}"}

      arms == [] or not Enum.all?(arms, &match?({n, _} when is_binary(n), &1)) ->
        {:error,
         "Sweep: expected :arms to be a non-empty list of {name, opts}, got: #{inspect(arms)}"}

      arms |> Enum.map(&elem(&1, 0)) |> Enum.uniq() |> length() != length(arms) ->
        {:error,
         "Sweep: expected arm names to be unique, got: #{inspect(Enum.map(arms, &elem(&1, 0)))}"}

      seeds == [] or not Enum.all?(seeds, &is_integer/1) ->
        {:error, "Sweep: expected :seeds to be a non-empty list of integers"}

      not (is_function(spec[:run], 2) or (is_atom(spec[:scenario]) and spec[:scenario] != nil)) ->
        {:error, "Sweep: expected :run (a function of arm and seed) or :scenario (a module)"}

      true ->
        metrics = Enum.map(Map.get(spec, :metrics, []), &metric/1)
        titles = for {m, _, title} <- Map.get(spec, :metrics, []), into: %{}, do: {m, title}
        names = Enum.map(arms, &elem(&1, 0))

        tests =
          Enum.map(Map.get(spec, :tests, []), fn
            {a, alt, b, m} -> {a, alt, b, m, []}
            other -> other
          end)

        bad_test =
          Enum.find(tests, fn
            {a, alt, b, m, opts} when is_list(opts) ->
              not (a in names and b in names and alt in [:greater, :less] and
                     Keyword.has_key?(metrics, m))

            _ ->
              true
          end)

        if bad_test do
          {:error,
           "Sweep: expected tests {arm, :greater | :less, arm, metric} over the arms and " <>
             "metrics, got: #{inspect(bad_test)}"}
        else
          {:ok,
           %{
             name: name,
             title: Map.get(spec, :title, name),
             subtitle: Map.get(spec, :subtitle),
             arms: Enum.map(arms, fn {n, o} -> %{name: n, opts: o} end),
             seeds: seeds,
             run: runner(spec),
             order: Map.get(spec, :order, :seed_major),
             metrics: metrics,
             titles: titles,
             tests: tests,
             csv: Map.get(spec, :csv),
             summary: Map.get(spec, :summary, fn _ -> %{} end),
             write: Map.get(spec, :write, fn _, _ -> [] end),
             report: Map.get(spec, :report, fn _ -> [] end),
             concurrency: Map.get(spec, :concurrency, System.schedulers_online())
           }}
        end
    end
  end

  defp metric({name, key, _title}), do: metric({name, key})
  defp metric({name, key}) when is_atom(key), do: {name, &Map.get(&1, key)}
  defp metric({name, fun}) when is_function(fun, 1), do: {name, fun}

  defp runner(%{run: run}) when is_function(run, 2), do: run

  defp runner(%{scenario: module} = spec) do
    # A run's own progress line stays off (the sweep draws a line per run), even when the
    # run asked for progress (`TartarusTools.Progress.force/1`).
    base = Keyword.merge([quiet: true, progress_device: false], Map.get(spec, :base, []))

    fn arm, seed ->
      {:ok, r} = TartarusEmu.Scenario.run(module, base ++ arm.opts ++ [seed: seed, out: false])

      {r.summary, r.series}
    end
  end

  # -- running ----------------------------------------------------------------------------

  defp plan(%{order: :arm_major} = spec), do: for(a <- spec.arms, s <- spec.seeds, do: {a, s})
  defp plan(spec), do: for(s <- spec.seeds, a <- spec.arms, do: {a, s})

  defp run_all(spec, o) do
    plan = plan(spec)
    total = length(plan)
    # Virtual time is the VM's: runs in it go one at a time.
    concurrency = if o.time == :virtual, do: 1, else: Map.get(o, :concurrency) || spec.concurrency

    t0 = Clock.machine_time(:millisecond)
    # The standard devices get the lines only when they are a terminal, unless the run
    # asked for progress (a mix task's --progress: TartarusTools.Progress.force/1).
    quiet? =
      not TartarusTools.Progress.forced?() and
        (o.quiet or
           (o.progress_device in [:standard_error, :standard_io] and
              not tty?(o.progress_device)))

    plan
    |> Task.async_stream(
      fn {arm, seed} -> run_alone(spec.run, arm, seed, o) end,
      max_concurrency: concurrency,
      ordered: false,
      timeout: :infinity
    )
    |> Stream.with_index(1)
    |> Enum.map(fn {{:ok, run}, done} ->
      unless quiet? do
        secs = :erlang.float_to_binary(run.ms / 1000, decimals: 1)

        # What, k of n, elapsed and ETA (from the mean time per run so far).
        elapsed = Clock.machine_time(:millisecond) - t0
        eta = div(elapsed * (total - done), done)

        IO.puts(
          o.progress_device,
          "#{spec.name} [#{done}/#{total}] #{run.arm} seed #{run.seed} (#{secs} s)  " <>
            "elapsed #{clock(elapsed)}  ETA #{clock(eta)}"
        )
      end

      run
    end)
    |> order_as(plan)
  end

  # A run in virtual time goes in a fresh VM of its own when its function can be loaded
  # there (TartarusEmu.FreshVM: a run that shares a VM with earlier ones does not always
  # replay exactly); otherwise (a function of a script or a test file), here.
  defp run_alone(fun, arm, seed, o) do
    time = o.time

    one = fn ->
      Tartarus.Clock.Virtual.within(time, seed, fn ->
        fun |> run_one(arm, seed) |> with_clock()
      end)
    end

    if time == :virtual and o.fresh_vm and TartarusEmu.FreshVM.portable?({fun, arm}) do
      one |> TartarusEmu.FreshVM.run(apps: apps(fun)) |> Map.put(:vm, :fresh)
    else
      one.() |> Map.put(:vm, :this)
    end
  end

  # The run function's application (and so its dependencies) and the emulator's.
  defp apps(fun) do
    {:module, m} = Function.info(fun, :module)

    case Application.get_application(m) do
      nil -> [:tartarus_emu]
      app -> Enum.uniq([app, :tartarus_emu])
    end
  end

  defp tty?(device) do
    match?({:ok, _}, :io.columns(device))
  rescue
    _ -> false
  end

  defp clock(ms) do
    s = div(ms, 1000)
    pad = &String.pad_leading(Integer.to_string(&1), 2, "0")

    if s >= 3600,
      do: "#{div(s, 3600)}:#{pad.(div(rem(s, 3600), 60))}:#{pad.(rem(s, 60))}",
      else: "#{div(s, 60)}:#{pad.(rem(s, 60))}"
  end

  defp run_one(fun, arm, seed) do
    t0 = Clock.machine_time(:millisecond)

    {summary, data} =
      case fun.(arm, seed) do
        {summary, data} when is_map(summary) -> {summary, data}
        summary when is_map(summary) -> {summary, nil}
      end

    ms = Clock.machine_time(:millisecond) - t0
    %{arm: arm.name, opts: arm.opts, seed: seed, summary: summary, data: data, ms: ms}
  end

  # In virtual time, what the clock did (since its install): the run's record gets `clock:`.
  defp with_clock(run) do
    case Tartarus.Clock.Virtual.stats() do
      nil -> run
      st -> Map.put(run, :clock, Map.take(st, [:virtual_ms, :fired, :dirty_overlaps]))
    end
  end

  # Whether the runs in virtual time can be replayed exactly: readings of the clock that saw
  # a heap collected on a dirty scheduler beside a runnable process (Virtual.stats/0).
  defp replay(runs) do
    case for(%{clock: c} <- runs, do: c.dirty_overlaps) do
      [] ->
        %{}

      overlaps ->
        %{
          replay: %{
            dirty_overlaps: Enum.sum(overlaps),
            runs_with_overlaps: Enum.count(overlaps, &(&1 > 0))
          }
        }
    end
  end

  defp order_as(runs, plan) do
    index = Map.new(runs, &{{&1.arm, &1.seed}, &1})
    Enum.map(plan, fn {arm, seed} -> Map.fetch!(index, {arm.name, seed}) end)
  end

  # -- statistics -------------------------------------------------------------------------

  defp values(runs, fun), do: Enum.map(runs, &fun.(&1.summary))

  defp aggregate(runs, spec) do
    for {arm, rs} <- by_arm(runs, Enum.map(spec.arms, & &1.name)), into: %{} do
      {arm, Map.new(spec.metrics, fn {m, f} -> {m, Stats.describe(values(rs, f))} end)}
    end
  end

  defp test({a, alt, b, m, opts}, runs, spec) do
    f = Keyword.fetch!(spec.metrics, m)
    xs = for r <- runs, r.arm == a, v = f.(r.summary), v != nil, do: v
    ys = for r <- runs, r.arm == b, v = f.(r.summary), v != nil, do: v

    Stats.mann_whitney(xs, ys, Keyword.put(opts, :alternative, alt))
    |> Map.merge(%{a: a, alternative: alt, b: b, metric: m})
  end

  # -- files ------------------------------------------------------------------------------

  defp write(dir, spec, result) do
    File.mkdir_p!(dir)

    {header, rows} =
      case spec.csv do
        {header, fun} ->
          {header, Enum.flat_map(result.runs, fun)}

        nil ->
          {["arm", "seed" | Enum.map(spec.metrics, &to_string(elem(&1, 0)))],
           for(
             r <- result.runs,
             do: [r.arm, r.seed | Enum.map(spec.metrics, fn {_, f} -> f.(r.summary) end)]
           )}
      end

    csv = Report.write_csv!(dir, "runs", header, rows)
    names = Enum.map(spec.arms, & &1.name)
    groups = by_arm(result.runs, names)

    boxes =
      if Enum.any?(groups, fn {_, rs} -> length(rs) > 1 end) do
        for {m, f} <- spec.metrics do
          plot =
            SVG.box_plot(
              Enum.map(groups, fn {arm, rs} -> {arm, Enum.reject(values(rs, f), &is_nil/1)} end),
              title: Map.get(spec.titles, m, "#{spec.name}: #{m} per run"),
              subtitle:
                Enum.join(Enum.reject([spec.subtitle, seeds_note(result.runs)], &is_nil/1), "; "),
              y_label: to_string(m)
            )

          SVG.write!(Path.join(dir, "#{m}.svg"), plot)
        end
      else
        []
      end

    extra = spec.write.(dir, result)
    report = spec.report.(result.summary)

    summaries =
      Report.write_summary!(dir, Keyword.get(report, :summary, result.summary),
        title: spec.title,
        comparisons: Keyword.get(report, :comparisons, []),
        markdown: Keyword.get(report, :markdown)
      )

    [csv | boxes] ++ extra ++ summaries
  end

  # "seeds 1-10" (or the list when not a range): what the box plots were drawn from.
  defp seeds_note(runs) do
    seeds = runs |> Enum.map(& &1.seed) |> Enum.uniq() |> Enum.sort()

    cond do
      seeds == [] ->
        "no runs"

      is_integer(hd(seeds)) and seeds == Enum.to_list(hd(seeds)..List.last(seeds)) and
          length(seeds) > 1 ->
        "seeds #{hd(seeds)}-#{List.last(seeds)}"

      true ->
        "seeds " <> Enum.map_join(seeds, ", ", &to_string/1)
    end
  end
end
