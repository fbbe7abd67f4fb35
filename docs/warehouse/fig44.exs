# Draws docs/warehouse/fig44_scaling_issue25.svg (Fig. 4.4 under the thesis's load, issue 25) and
# docs/warehouse/fig44_service_issue25.svg (the central processes' queues over time) from the runs
# of the pre-registration in docs/warehouse.md ("Fig. 4.4 under the thesis's load"):
#
#   A:  mix tartarus.warehouse --experiment scaling --designs central --seeds 3 --seed 11 --out DIR/A --json
#   B:  for s in 11 12 13; do
#         mix tartarus.warehouse --experiment scaling --designs guided,guided_continue --seeds 1 --seed $s --out DIR/B$s --json
#       done
#   C:  for s in 11 12 13; do for n in 5 10 20 30 45 60; do
#         mix tartarus.warehouse --experiment scaling --designs agents,agents_continue --sizes $n --seeds 1 --seed $s --out DIR/C$s-$n --json
#       done; done
#       (the first, loaded run had seed 11 only, in DIR/C$n)
#   mix run docs/warehouse/fig44.exs DIR
#
# It prints the combined curves (medians over the seeds present, TartarusTools.Stats.median)
# and where each agents' curve crosses the central one, as JSON.
[dir] = System.argv()

alias Tartarus.JSON
alias TartarusTools.{Stats, SVG}
alias TartarusWarehouse.Experiment.Scaling

read = fn name ->
  path = Path.join([dir, name, "summary.json"])
  if File.exists?(path), do: path |> File.read!() |> JSON.decode!()
end

a = read.("A")
bs = Enum.reject(Enum.map([11, 12, 13], &read.("B#{&1}")), &is_nil/1)

c_dirs =
  for n <- [5, 10, 20, 30, 45, 60],
      sub <- ["C#{n}" | Enum.map([11, 12, 13], &"C#{&1}-#{n}")],
      do: sub

cs = Enum.reject(Enum.map(c_dirs, read), &is_nil/1)
c_seeds = cs |> Enum.map(& &1["seed"]) |> Enum.uniq() |> Enum.sort() |> Enum.join(", ")

# A curve from summaries: size => median of every value present.
curve = fn summaries, key ->
  summaries
  |> Enum.flat_map(&Map.to_list(&1[key] || %{}))
  |> Enum.reject(fn {_, v} -> v == nil end)
  |> Enum.group_by(fn {n, _} -> n end, fn {_, v} -> v end)
  |> Map.new(fn {n, vs} -> {n, Float.round(Stats.median(vs) * 1.0, 3)} end)
end

points = fn m -> m |> Enum.map(fn {n, v} -> {String.to_integer(n), v} end) |> Enum.sort() end

central = curve.([a], "avg_task_ms_central")

agents = %{
  "agents_guided" => curve.(bs, "avg_task_ms_agents_guided"),
  "agents_guided_continue" => curve.(bs, "avg_task_ms_agents_guided_continue"),
  "agents" => curve.(cs, "avg_task_ms_agents"),
  "agents_continue" => curve.(cs, "avg_task_ms_agents_continue")
}

labels = %{
  "agents_guided" => "agents, guided, returning",
  "agents_guided_continue" => "agents, guided, continuing",
  "agents" => "agents, blind, returning",
  "agents_continue" => "agents, blind, continuing"
}

predicted = a["predicted_central_ms"]

# The blind agents that continue are off any readable scale (seconds a task, most jobs
# unfinished by the floor's timeout): their values go in the note, not on the chart.
series =
  [%{name: "central server", points: points.(central)}] ++
    for k <- ["agents_guided", "agents_guided_continue", "agents"],
        agents[k] != %{},
        do: %{name: labels[k], points: points.(agents[k])}

off_chart =
  agents["agents_continue"]
  |> points.()
  |> Enum.map_join(", ", fn {n, v} -> "#{n}: #{Float.round(v / 1000, 1)} s" end)

SVG.write!(
  "docs/warehouse/fig44_scaling_issue25.svg",
  SVG.line_chart(series,
    title: "Average time per task against tasks per job (Fig. 4.4, under the thesis's load)",
    subtitle:
      "60 robots, 100 nodes, 120 jobs (11-110 counted), 200 ms tasks, S = 2.2 ms; medians (blind: seeds #{c_seeds})",
    references: [%{name: "central, predicted", points: points.(predicted)}],
    note: "Off the chart, blind agents continuing (seeds #{c_seeds}): #{off_chart} a task.",
    x_label: "tasks per job",
    y_label: "time per task",
    y_unit: "ms",
    y_min: 0
  )
)

# The queues over time at 60 tasks per job, seed 11: the central server (A) and the guided
# agents' distributor (B11).
queue = fn sub, file, name ->
  path = Path.join([dir, sub, file])

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
  queue.("A", "queue_central.csv", "central server") ++
    queue.("B11", "queue_guided.csv", "distributor, guided agents returning")

if qs != [] do
  SVG.write!(
    "docs/warehouse/fig44_service_issue25.svg",
    SVG.line_chart(qs,
      title: "Messages waiting or in service at the central process, 60 tasks per job",
      subtitle: "seed 11, S = 2.2 ms a message, 50 ms bins",
      x_label: "time",
      x_unit: "ms",
      y_label: "queue",
      y_unit: "messages",
      y_min: 0,
      markers: false
    )
  )
end

IO.puts(
  JSON.encode!(%{
    avg_task_ms_central: central,
    avg_task_ms_agents: agents,
    predicted_central_ms: predicted,
    central_fit: a["central_fit"],
    central_rise: a["central_rise"],
    utilisation_central: a["utilisation"]["central"],
    # the distributor's busy fraction, per design: size => median over the seeds present
    utilisation_distributor: %{
      "agents_guided" => curve.(Enum.map(bs, & &1["utilisation"]), "distributor_agents_guided"),
      "agents_guided_continue" =>
        curve.(Enum.map(bs, & &1["utilisation"]), "distributor_agents_guided_continue"),
      "agents" => curve.(Enum.map(cs, & &1["utilisation"]), "distributor_agents"),
      "agents_continue" =>
        curve.(Enum.map(cs, & &1["utilisation"]), "distributor_agents_continue")
    },
    crossings: Map.new(agents, fn {k, v} -> {k, Scaling.crossing(v, central)} end),
    mutex_violations: Enum.sum(Enum.map([a | bs ++ cs], & &1["mutex_violations"])),
    deadlocks: Enum.sum(Enum.map([a | bs ++ cs], & &1["deadlocks"])),
    # floors run: a sweep run is a point (size, seed) and runs one floor per design
    floors:
      Enum.sum(
        Enum.map([a | bs ++ cs], &(&1["sweep"]["runs"] * map_size(&1["avg_task_ms_by_seed"])))
      )
  })
)
