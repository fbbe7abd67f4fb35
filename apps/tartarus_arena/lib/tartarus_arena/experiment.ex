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

  Pure apart from writing the outputs and reading the wall clock for the speed figure;
  the same seed gives the same numbers (except `sim_speed_x` and `wall_ms`).
  """

  alias TartarusArena.{PFAs, Paths, PFA, Render, Run, World}

  @schema [
    seed: [
      type: :pos_integer,
      default: 1,
      doc: "seed of the world's noise and the features' jitter"
    ],
    laps: [type: :pos_integer, default: 3, doc: "laps per PFA and path"],
    bench_seconds: [type: :pos_integer, default: 120, doc: "simulated seconds of the speed run"],
    out: [type: :string, doc: "output directory (default results/arena-<UTC timestamp>)"]
  ]

  @doc "The options' schema (`Tartarus.Options`)."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Runs the experiment and writes its outputs into `out`: `lap_times.csv`,
  `subpaths.csv`, `trajectories_A1.svg` .. `trajectories_A8.svg`, `snapshot.svg`,
  `camera.png`, `summary.json`, `summary.md`. Returns `{:ok, %{summary:, out:}}` or
  `{:error, message}` for bad options.
  """
  @spec run(keyword()) :: {:ok, %{summary: map(), out: Path.t()}} | {:error, String.t()}
  def run(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusArena.Experiment.run/1") do
      {:ok, do_run(opts)}
    end
  end

  defp do_run(opts) do
    t0 = System.monotonic_time(:millisecond)
    seed = opts[:seed]
    out = opts[:out] || Path.join("results", "arena-#{timestamp()}")
    File.mkdir_p!(out)
    p1 = Paths.path(1, seed)
    p2 = Paths.path(2, seed)

    laps =
      for pfa <- PFAs.all() do
        world = Run.arena([{:p1, p1, 0.0}, {:p2, p2, 0.0}], seed: {seed, PFAs.name(pfa)})

        res =
          Run.laps(
            [%{robot: :p1, path: p1, choose: pfa}, %{robot: :p2, path: p2, choose: pfa}],
            world,
            laps: opts[:laps],
            max_time: 90.0 * opts[:laps]
          )

        trajs = %{
          "path 1 (#{PFAs.name(pfa)})" => res.robots.p1.trajectory,
          "path 2 (#{PFAs.name(pfa)})" => res.robots.p2.trajectory
        }

        Render.trajectories(res.world, trajs, title: "#{PFAs.name(pfa)}: #{opts[:laps]} laps")
        |> then(&File.write!(Path.join(out, "trajectories_#{PFAs.name(pfa)}.svg"), &1))

        {PFAs.name(pfa), res}
      end

    {_, last} = List.last(laps)
    File.write!(Path.join(out, "snapshot.svg"), Render.svg(last.world))

    File.write!(
      Path.join(out, "camera.png"),
      Render.png(last.world, center: {1.5, 1.5}, view: 3.0, pixels: {300, 300})
    )

    subs =
      for pfa <- PFAs.all(), p <- [p1, p2], sp <- p.subpaths do
        Run.subpath(pfa, p, sp.index, seed: seed)
      end

    {speed, speed_cpu, bench_world} = sim_speed_both(p1, p2, seed, opts[:bench_seconds])
    File.write!(Path.join(out, "bench_snapshot.svg"), Render.svg(bench_world))

    write_csv(
      Path.join(out, "lap_times.csv"),
      ["pfa", "path", "lap", "seconds"],
      for(
        {name, res} <- laps,
        {id, robot} <- [{1, :p1}, {2, :p2}],
        {t, i} <- Enum.with_index(res.robots[robot].lap_times, 1),
        do: [name, id, i, t]
      )
    )

    write_csv(
      Path.join(out, "subpaths.csv"),
      ["pfa", "path", "index", "type", "completed", "time", "on_line", "cost"],
      for(s <- subs, do: [s.pfa, s.path, s.index, s.type, s.completed, s.time, s.on_line, s.cost])
    )

    cost =
      for type <- Paths.types(), into: %{} do
        {type,
         for pfa <- PFAs.all(), into: %{} do
           cs = for s <- subs, s.type == type, s.pfa == PFAs.name(pfa), do: s.cost
           {PFAs.name(pfa), Float.round(TartarusTools.Stats.mean(cs), 3)}
         end}
      end

    summary = %{
      seed: seed,
      laps: opts[:laps],
      lap_times:
        Map.new(laps, fn {name, res} ->
          {name, %{path1: res.robots.p1.lap_times, path2: res.robots.p2.lap_times}}
        end),
      lost:
        Map.new(laps, fn {name, res} ->
          {name, %{path1: res.robots.p1.lost, path2: res.robots.p2.lost}}
        end),
      path_length_m: %{path1: Float.round(p1.length, 3), path2: Float.round(p2.length, 3)},
      subpath_cost: cost,
      exhaustive_best:
        Map.new(cost, fn {type, m} -> {type, m |> Enum.min_by(&elem(&1, 1)) |> elem(0)} end),
      sim_speed_x: speed,
      sim_speed_cpu_x: speed_cpu,
      sim_speed_robots: 3,
      bench_seconds: opts[:bench_seconds],
      wall_ms: System.monotonic_time(:millisecond) - t0
    }

    File.write!(Path.join(out, "summary.json"), TartarusTools.JSON.encode!(summary) <> "\n")
    File.write!(Path.join(out, "summary.md"), markdown(summary))
    %{summary: summary, out: out}
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
    t0 = System.monotonic_time(:microsecond)
    {cpu0, _} = :erlang.statistics(:runtime)
    res = Run.laps(drivers, world, laps: 1_000_000, max_time: seconds * 1.0)
    {cpu1, _} = :erlang.statistics(:runtime)
    wall = (System.monotonic_time(:microsecond) - t0) / 1.0e6
    cpu = max(cpu1 - cpu0, 1) / 1000
    {Float.round(res.time / wall, 1), Float.round(res.time / cpu, 1), res.world}
  end

  defp write_csv(path, header, rows) do
    lines = [Enum.join(header, ",") | Enum.map(rows, &Enum.join(&1, ","))]
    File.write!(path, Enum.join(lines, "\n") <> "\n")
  end

  defp markdown(s) do
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
    # Arena run (seed #{s.seed})

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

  defp timestamp do
    DateTime.utc_now()
    |> DateTime.truncate(:second)
    |> DateTime.to_iso8601(:basic)
    |> String.replace("Z", "")
  end
end
