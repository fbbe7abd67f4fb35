# Fig. 4.4 in virtual time (issue 39): reads the summaries of the registered runs in
# docs/warehouse.md ("Fig. 4.4 in virtual time") and draws
#
#   docs/warehouse/fig44_scaling.svg  the judged run: medians over seeds 2101-2110, with
#                                     quartile bars, central server and blind agents
#   docs/warehouse/fig44_map.svg      which design is faster, per setting (L, k, S) and size
#   docs/warehouse/fig44_service.svg  the central server's and the distributor's queues over
#                                     time at 60 tasks per job, seed 2101
#
# and prints, as JSON, the table of the note: per size the median and quartiles of each
# design, the hops per task, the utilisation and longest queues, the census (violations,
# deadlocks, jobs done) and the thesis's four statements (Scaling.criteria/2).
#
#   mix run docs/warehouse/fig44_vt.exs DIR
#
# DIR holds `<name>.json` (a summary, `mix tartarus.warehouse ... --json`) and `<name>/` (its
# output directory) for each run of the queue: judged-S, map-L<L>-k<k>-S<S>-<seed>, guided-S,
# and the racks' check: racks-S and base-S.
[dir] = System.argv()

alias Tartarus.JSON
alias TartarusTools.{Stats, SVG}
alias TartarusWarehouse.Experiment.Scaling

sizes = [5, 10, 20, 30, 40, 50, 60]

summaries =
  dir
  |> Path.join("*.json")
  |> Path.wildcard()
  |> Map.new(fn path -> {Path.basename(path, ".json"), path |> File.read!() |> JSON.decode!()} end)

# Per design and size, the values of the runs named: {seed, value} in seed order.
values = fn names, design, key ->
  Map.new(sizes, fn n ->
    vs =
      for name <- names,
          s = summaries[name],
          s != nil,
          v = get_in(s, [key, design, to_string(n)]),
          v != nil,
          do: if(is_list(v), do: hd(v), else: v)

    {n, vs}
  end)
end

stat = fn vs ->
  case vs do
    [] ->
      nil

    _ ->
      [q1, q3] = Stats.quantiles(vs, [0.25, 0.75])
      %{median: Float.round(Stats.median_mid(vs) * 1.0, 3), q1: q1, q3: q3, n: length(vs)}
  end
end

curve = fn names, design ->
  Map.new(values.(names, design, "avg_task_ms_by_seed"), fn {n, vs} -> {n, stat.(vs)} end)
end

medians = fn c -> for {n, %{median: m}} <- c, into: %{}, do: {to_string(n), m} end

judged = for s <- 2101..2110, summaries["judged-#{s}"], do: "judged-#{s}"
central = curve.(judged, "central")
agents = curve.(judged, "agents")

guided =
  curve.(for(s <- 2101..2103, summaries["guided-#{s}"], do: "guided-#{s}"), "agents_guided")

med_of = fn names, key, who ->
  Map.new(values.(names, who, key), fn {n, vs} ->
    {to_string(n), if(vs == [], do: nil, else: Stats.median_mid(vs))}
  end)
end

# Per run named: violations, deadlocks, jobs submitted and done.
census_of = fn names ->
  Map.new(names, fn name ->
    s = summaries[name]

    {name,
     %{
       violations: s["mutex_violations"],
       deadlocks: s["deadlocks"],
       jobs: s["jobs"],
       completed: s["completed_jobs"]
     }}
  end)
end

census = census_of.(judged)

# The judged figure: medians with quartile bars.
series = fn name, c ->
  pts = for n <- sizes, st = c[n], st != nil, do: {n, st.median}
  bars = for n <- sizes, st = c[n], st != nil, do: {n, st.q1 * 1.0, st.q3 * 1.0}
  %{name: name, points: pts, intervals: bars}
end

chart =
  [series.("central server", central), series.("blind agents returning (the thesis's)", agents)] ++
    if(guided |> Map.values() |> Enum.any?(),
      do: [series.("guided agents (beyond the thesis)", guided)],
      else: []
    )

n_judged = length(judged)

SVG.write!(
  "docs/warehouse/fig44_scaling.svg",
  SVG.line_chart(chart,
    title: "Time per task against tasks per job (Fig. 4.4), virtual time",
    subtitle:
      "60 robots, 100 nodes, n + 20 jobs (10 + 10 not counted), 2 s tasks, L = 10 ms a link, S = 5 ms a message; medians of #{n_judged} seeds",
    note:
      "Bars: quartiles over the seeds (nearest rank)." <>
        if(length(chart) > 2, do: " Guided agents: seeds 2101-2103.", else: ""),
    x_label: "tasks per job",
    y_label: "time per task",
    y_unit: "ms",
    y_min: 0
  )
)

# The map: per cell (L, k, S), which design has the lower median, with the ratio agents /
# central written in the cell.
cells = [
  {10, 60, 5, Enum.map(2101..2103, &"judged-#{&1}")},
  {10, 60, 1, Enum.map(2201..2203, &"map-L10-k60-S1-#{&1}")},
  {10, 20, 5, Enum.map(2201..2203, &"map-L10-k20-S5-#{&1}")},
  {10, 20, 1, Enum.map(2201..2203, &"map-L10-k20-S1-#{&1}")},
  {1, 60, 5, Enum.map(2201..2203, &"map-L1-k60-S5-#{&1}")},
  {1, 60, 1, Enum.map(2201..2203, &"map-L1-k60-S1-#{&1}")},
  {1, 20, 5, Enum.map(2201..2203, &"map-L1-k20-S5-#{&1}")},
  {1, 20, 1, Enum.map(2201..2203, &"map-L1-k20-S1-#{&1}")}
]

row_name = fn l, k, s -> "L #{l} ms, k #{k}, S #{s} ms" end

map =
  for {l, k, s, names} <- cells,
      present = Enum.filter(names, &summaries[&1]),
      length(present) == length(names),
      c = medians.(curve.(present, "central")),
      a = medians.(curve.(present, "agents")),
      n <- sizes,
      c[to_string(n)] != nil and a[to_string(n)] != nil,
      into: %{} do
    ratio = a[to_string(n)] / c[to_string(n)]
    class = if ratio < 1, do: :agents, else: :central
    {{row_name.(l, k, s), n}, %{class: class, label: :erlang.float_to_binary(ratio, decimals: 2)}}
  end

SVG.write!(
  "docs/warehouse/fig44_map.svg",
  SVG.grid_chart(Enum.map(cells, fn {l, k, s, _} -> row_name.(l, k, s) end), sizes, map,
    classes: [central: "central server faster", agents: "blind agents faster"],
    title: "When to decentralize: the faster design per setting and size",
    subtitle:
      "k robots, L ms a link, S ms a message served; in each cell the blind agents' median time per task over the central server's (3 seeds)",
    note:
      "L = 10, k = 60, S = 5 is the judged run's seeds 2101-2103, the other cells seeds 2201-2203; grey: not run.",
    x_label: "tasks per job",
    y_label: "setting",
    width: 900,
    height: 360
  )
)

# The queues over time at 60 tasks per job, seed 2101.
queue = fn file, name ->
  path = Path.join([dir, "judged-2101", file])

  if File.exists?(path) do
    [_ | rows] = path |> File.read!() |> String.split("\n", trim: true)

    pts =
      for row <- rows, [t, q] = String.split(row, ","), q != "" do
        {String.to_integer(t), elem(Float.parse(q), 0)}
      end

    [%{name: name, points: pts}]
  else
    []
  end
end

qs =
  queue.("queue_central.csv", "central server") ++
    queue.("queue_agents.csv", "distributor, blind agents")

if qs != [] do
  SVG.write!(
    "docs/warehouse/fig44_service.svg",
    SVG.line_chart(qs,
      title: "Messages waiting or in service at the central process, 60 tasks per job",
      subtitle: "seed 2101, S = 5 ms a message, 50 ms bins, virtual time",
      x_label: "time",
      x_unit: "ms",
      y_label: "queue",
      y_unit: "messages",
      y_min: 0,
      markers: false
    )
  )
end

show = fn c -> Map.new(c, fn {n, st} -> {to_string(n), st} end) end

# The racks of §4.7.1 (registered 2026-12-06, d317879): the judged command with
# --phi-agents on seeds 2101-2110 (racks-S), and the paired baseline without them at the
# same commit, agents only, on 2101-2103 (base-S): ms a task, racks minus none, per seed.
racks = for s <- 2101..2110, summaries["racks-#{s}"], do: "racks-#{s}"
racks_central = curve.(racks, "central")
racks_agents = curve.(racks, "agents")

paired =
  for s <- 2101..2103,
      r = summaries["racks-#{s}"],
      b = summaries["base-#{s}"],
      r != nil and b != nil,
      into: %{} do
    diff =
      Map.new(sizes, fn n ->
        k = to_string(n)
        [rv] = r["avg_task_ms_by_seed"]["agents"][k]
        [bv] = b["avg_task_ms_by_seed"]["agents"][k]
        {k, Float.round(rv - bv, 3)}
      end)

    {"#{s}", diff}
  end

racks_report =
  if racks == [],
    do: nil,
    else: %{
      seeds: racks,
      central: show.(racks_central),
      agents: show.(racks_agents),
      criteria: Scaling.criteria(medians.(racks_central), medians.(racks_agents)),
      hops_per_task: med_of.(racks, "hops_per_task", "agents"),
      census:
        census_of.(racks ++ Enum.filter(Enum.map(2101..2103, &"base-#{&1}"), &summaries[&1])),
      paired_racks_minus_none_ms: paired
    }

IO.puts(
  JSON.encode!(%{
    seeds: judged,
    central: show.(central),
    agents: show.(agents),
    guided: show.(guided),
    hops_per_task: %{
      agents: med_of.(judged, "hops_per_task", "agents"),
      guided:
        med_of.(
          Enum.filter(Enum.map(2101..2103, &"guided-#{&1}"), &summaries[&1]),
          "hops_per_task",
          "agents_guided"
        )
    },
    utilisation: %{
      central: med_of.(judged, "utilisation", "central"),
      distributor: med_of.(judged, "utilisation", "distributor_agents")
    },
    max_queue: %{
      central: med_of.(judged, "max_queue", "central"),
      distributor: med_of.(judged, "max_queue", "distributor_agents")
    },
    census: census,
    criteria: Scaling.criteria(medians.(central), medians.(agents)),
    map: Map.new(map, fn {{row, n}, v} -> {"#{row} | #{n}", v} end),
    racks: racks_report
  })
)
