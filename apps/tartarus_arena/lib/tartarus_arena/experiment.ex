defmodule TartarusArena.Experiment do
  @moduledoc """
  The arena run behind `mix tartarus.arena`: every PFA for laps on both paths, every PFA
  over every sub-path instance, pictures, and the simulator's speed with three robots.

  1. **Laps**: for each PFA A1..A8, one robot on path 1 and one on path 2 at once, each
     driven by that PFA everywhere, for `laps` laps (`TartarusArena.Run.laps/3`): lap times
     per path, how often a robot was lost and put back, and a trajectory SVG per PFA.
  2. **Sub-paths**: each PFA alone over each sub-path instance of both paths
     (`TartarusArena.Run.subpath/4`): time, staying on the line, cost. The PFA of least
     mean cost per sub-path type is reported as `exhaustive_best`: what trying everything
     finds, the reference a selection mechanism (the immune experiment) can be held to.
     This is a measurement, not a selection mechanism.
  3. **Speed**: three robots (two on path 1 half a lap apart, one on path 2) driven by A4
     for `bench_seconds` of simulated time; `sim_speed_x` is simulated seconds per wall
     second (sensing, control, stepping and tracking included).

  Laps and sub-paths are a `TartarusEmu.Sweep` with a PFA an arm and the seed its only
  seed: the PFAs run in parallel, each in its own process (the speed run goes alone,
  before them), and the sweep writes `runs.csv` (a row per PFA: its mean lap time and
  put-backs per path, its mean sub-path cost) and adds `sweep` (those per arm) to the
  summary.

  Pure apart from writing the outputs and reading the wall clock for the speed figure;
  the same seed gives the same numbers (except `sim_speed_x`, `sim_speed_cpu_x` and
  `wall_ms`).
  """

  alias Tartarus.Clock
  alias TartarusArena.{PFAs, Paths, PFA, Render, Run, World}
  alias TartarusEmu.Sweep
  alias TartarusTools.{Report, Stats, SVG}

  @schema [
    seed: [
      type: :pos_integer,
      default: 1,
      doc: "seed of the world's noise and the features' jitter"
    ],
    laps: [type: :pos_integer, default: 3, doc: "laps per PFA and path"],
    bench_seconds: [type: :pos_integer, default: 120, doc: "simulated seconds of the speed run"],
    out: [type: :string, doc: "output directory (default results/arena-<UTC time>)"]
  ]

  @doc "The options' schema (`Tartarus.Options`)."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Runs the experiment and writes its outputs into `out`: `lap_times.csv`,
  `subpaths.csv`, `trajectories_A1.svg` .. `trajectories_A8.svg`, `snapshot.svg`,
  `bench_snapshot.svg`, `camera.png`, `runs.csv`, `summary.json`, `summary.md`. Returns `{:ok, %{summary:, out:}}` or
  `{:error, message}` for bad options.
  """
  @spec run(keyword()) :: {:ok, %{summary: map(), out: Path.t()}} | {:error, String.t()}
  def run(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusArena.Experiment.run/1") do
      {:ok, do_run(opts)}
    end
  end

  defp do_run(opts) do
    t0 = Clock.machine_time(:millisecond)
    seed = opts[:seed]
    p1 = Paths.path(1, seed)
    p2 = Paths.path(2, seed)
    # the speed run goes alone, before the PFAs' runs (which go in parallel)
    {speed, speed_cpu, bench_world} = sim_speed_both(p1, p2, seed, opts[:bench_seconds])

    spec = %{
      name: "arena",
      title: "Arena run (seed #{seed})",
      arms: Enum.map(PFAs.all(), &{PFAs.name(&1), &1}),
      seeds: [seed],
      run: fn arm, seed -> run_pfa(arm.opts, p1, p2, seed, opts[:laps]) end,
      metrics: [
        {:lap_path1, &mean3(&1.lap_times.path1), "mean lap time on path 1 (s)"},
        {:lap_path2, &mean3(&1.lap_times.path2), "mean lap time on path 2 (s)"},
        {:lost_path1, & &1.lost.path1, "put back on path 1"},
        {:lost_path2, & &1.lost.path2, "put back on path 2"},
        {:subpath_cost, &mean3(Enum.map(&1.subpaths, fn s -> s.cost end)),
         "mean cost over every sub-path instance (s)"}
      ],
      summary: fn r ->
        summarize(r.runs, seed, opts, p1, p2)
        |> Map.merge(%{
          sim_speed_x: speed,
          sim_speed_cpu_x: speed_cpu,
          sim_speed_robots: 3,
          bench_seconds: opts[:bench_seconds],
          wall_ms: Clock.machine_time(:millisecond) - t0
        })
      end,
      write: fn dir, r -> write(dir, r.runs, opts[:laps], bench_world) end,
      report: fn s -> [markdown: markdown(s)] end
    }

    {:ok, r} = Sweep.run(spec, out: opts[:out], quiet: true)
    %{summary: r.summary, out: r.out}
  end

  # one arm: `pfa` for laps on both paths at once, then alone over every sub-path instance
  defp run_pfa(pfa, p1, p2, seed, laps) do
    world = Run.arena([{:p1, p1, 0.0}, {:p2, p2, 0.0}], seed: {seed, PFAs.name(pfa)})

    res =
      Run.laps(
        [%{robot: :p1, path: p1, choose: pfa}, %{robot: :p2, path: p2, choose: pfa}],
        world,
        laps: laps,
        max_time: 90.0 * laps
      )

    subs = for p <- [p1, p2], sp <- p.subpaths, do: Run.subpath(pfa, p, sp.index, seed: seed)

    summary = %{
      pfa: PFAs.name(pfa),
      lap_times: %{path1: res.robots.p1.lap_times, path2: res.robots.p2.lap_times},
      lost: %{path1: res.robots.p1.lost, path2: res.robots.p2.lost},
      subpaths: subs
    }

    trajectories = %{
      "path 1 (#{PFAs.name(pfa)})" => res.robots.p1.trajectory,
      "path 2 (#{PFAs.name(pfa)})" => res.robots.p2.trajectory
    }

    {summary, %{world: res.world, trajectories: trajectories}}
  end

  defp mean3(xs), do: (m = Stats.mean(xs)) && Float.round(m, 3)

  defp summarize(runs, seed, opts, p1, p2) do
    subs = Enum.flat_map(runs, & &1.summary.subpaths)

    cost =
      for type <- Paths.types(), into: %{} do
        {type,
         for pfa <- PFAs.all(), into: %{} do
           cs = for s <- subs, s.type == type, s.pfa == PFAs.name(pfa), do: s.cost
           {PFAs.name(pfa), Float.round(Stats.mean(cs), 3)}
         end}
      end

    %{
      seed: seed,
      laps: opts[:laps],
      lap_times: Map.new(runs, &{&1.arm, &1.summary.lap_times}),
      lost: Map.new(runs, &{&1.arm, &1.summary.lost}),
      path_length_m: %{path1: Float.round(p1.length, 3), path2: Float.round(p2.length, 3)},
      subpath_cost: cost,
      exhaustive_best:
        Map.new(cost, fn {type, m} -> {type, m |> Enum.min_by(&elem(&1, 1)) |> elem(0)} end)
    }
  end

  defp write(out, runs, laps, bench_world) do
    trajectories =
      for run <- runs do
        svg =
          Render.trajectories(run.data.world, run.data.trajectories,
            title: "#{run.arm}: #{laps} laps on both paths at once",
            subtitle: "PFA #{run.arm}, one robot per path, #{laps} laps, seed #{run.seed}"
          )

        SVG.write!(Path.join(out, "trajectories_#{run.arm}.svg"), svg)
      end

    last = List.last(runs).data.world

    snapshot =
      SVG.write!(
        Path.join(out, "snapshot.svg"),
        Render.svg(last, subtitle: "the end of the last PFA's laps, seed #{List.last(runs).seed}")
      )

    camera = Path.join(out, "camera.png")
    File.write!(camera, Render.png(last, center: {1.5, 1.5}, view: 3.0, pixels: {300, 300}))
    bench = SVG.write!(Path.join(out, "bench_snapshot.svg"), Render.svg(bench_world))

    lap_times =
      Report.write_csv!(
        out,
        "lap_times",
        ["pfa", "path", "lap", "seconds"],
        for(
          run <- runs,
          {id, path} <- [{1, :path1}, {2, :path2}],
          {t, i} <- Enum.with_index(run.summary.lap_times[path], 1),
          do: [run.arm, id, i, t]
        )
      )

    subpaths =
      Report.write_csv!(
        out,
        "subpaths",
        ["pfa", "path", "index", "type", "completed", "time", "on_line", "cost"],
        for(
          run <- runs,
          s <- run.summary.subpaths,
          do: [s.pfa, s.path, s.index, s.type, s.completed, s.time, s.on_line, s.cost]
        )
      )

    trajectories ++ [snapshot, camera, bench, lap_times, subpaths]
  end

  @doc """
  Simulated seconds per wall second with three robots following lines with A4 for
  `seconds` of simulated time (two on path 1 half a lap apart, one on path 2). Returns the
  figure (rounded to 1) and the final world.
  """
  @spec sim_speed(Paths.t(), Paths.t(), term(), pos_integer()) :: {float(), World.t()}
  def sim_speed(p1, p2, seed, seconds) do
    {wall, _cpu, world} = sim_speed_both(p1, p2, seed, seconds)
    {wall, world}
  end

  @doc """
  As `sim_speed/4`, with also the speed against the VM's CPU time (`:erlang.statistics(:runtime)`,
  all schedulers): on a shared machine the wall-clock figure includes waiting for a core,
  the CPU figure does not. Returns `{wall_x, cpu_x, world}`.
  """
  @spec sim_speed_both(Paths.t(), Paths.t(), term(), pos_integer()) ::
          {float(), float(), World.t()}
  def sim_speed_both(p1, p2, seed, seconds) do
    world =
      Run.arena([{:a, p1, 0.0}, {:b, p1, p1.length / 2}, {:c, p2, 0.0}], seed: {seed, :bench})

    drivers = for {id, p} <- [a: p1, b: p1, c: p2], do: %{robot: id, path: p, choose: PFA.A4}
    t0 = Clock.machine_time(:microsecond)
    {cpu0, _} = :erlang.statistics(:runtime)
    res = Run.laps(drivers, world, laps: 1_000_000, max_time: seconds * 1.0)
    {cpu1, _} = :erlang.statistics(:runtime)
    wall = (Clock.machine_time(:microsecond) - t0) / 1.0e6
    cpu = max(cpu1 - cpu0, 1) / 1000
    {Float.round(res.time / wall, 1), Float.round(res.time / cpu, 1), res.world}
  end

  @doc """
  The arena's own tables in Markdown for summary `s` (what `summary.md` shows after the
  key table, and `mix tartarus.arena` prints): lap times and put-backs per PFA, mean
  cost per sub-path type and PFA, the simulator's speed.
  """
  @spec markdown(map()) :: String.t()
  def markdown(s) do
    pfas = Enum.map(PFAs.all(), &PFAs.name/1)

    lap_rows =
      for name <- pfas do
        lt = s.lap_times[name]

        "| #{name} | #{Enum.join(lt.path1, ", ")} | #{Enum.join(lt.path2, ", ")} | #{s.lost[name].path1} / #{s.lost[name].path2} |"
      end

    cost_rows =
      for type <- Paths.types() do
        "| #{type} | " <>
          Enum.map_join(pfas, " | ", &to_string(s.subpath_cost[type][&1])) <>
          " | #{s.exhaustive_best[type]} |"
      end

    """
    Lap times (s), #{s.laps} laps per PFA; path 1 is #{s.path_length_m.path1} m, path 2 #{s.path_length_m.path2} m.

    | PFA | path 1 | path 2 | lost (p1 / p2) |
    |---|---|---|---|
    #{Enum.join(lap_rows, "\n")}

    Mean cost per sub-path type (`time * (2 - on_line)`, s; a failed run costs 3 x its time limit):

    | type | #{Enum.join(pfas, " | ")} | least |
    |---|#{String.duplicate("---|", length(pfas))}---|
    #{Enum.join(cost_rows, "\n")}

    Simulator speed: #{s.sim_speed_x} x real time with #{s.sim_speed_robots} robots (#{s.bench_seconds} simulated s; #{s.sim_speed_cpu_x} x against the VM's CPU time).
    """
  end
end
