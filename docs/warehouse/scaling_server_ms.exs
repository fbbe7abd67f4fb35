# Before issue 25 (the flag was --server-ms, charged to the central server only; the metric
# was makespan / tasks; the current `scaling` runs another configuration, see
# docs/warehouse.md): kept to redraw the earlier figure from its runs.
#
# Regenerates docs/warehouse/scaling_server_ms.svg: the scaling experiment's average ms per
# task against tasks per job, the central server with a service time of 0, 1, 2 and 4 ms
# per robot message against the task agents, medians of seeds 1-3, from the
# `summary.json` of twelve runs (see docs/warehouse.md, "Experiments"):
#
#   for s in 0 1 2 4; do for seed in 1 2 3; do
#     mix tartarus.warehouse --experiment scaling --server-ms $s --seed $seed --out DIR/s$s-r$seed
#   done; done
#   mix run docs/warehouse/scaling_server_ms.exs DIR
#
# Run it on a quiet machine: the agents' design uses more CPU than one server, and the
# runs are in real time.
[dir] = System.argv()

median = fn xs ->
  xs = Enum.sort(xs)
  n = length(xs)
  if rem(n, 2) == 1, do: Enum.at(xs, div(n, 2)), else: (Enum.at(xs, div(n, 2) - 1) + Enum.at(xs, div(n, 2))) / 2
end

runs = fn s ->
  for seed <- 1..3 do
    dir |> Path.join("s#{s}-r#{seed}/summary.json") |> File.read!() |> Tartarus.JSON.decode!()
  end
end

curve = fn summaries, key ->
  summaries
  |> Enum.flat_map(&Map.to_list(&1[key]))
  |> Enum.group_by(fn {n, _} -> String.to_integer(n) end, fn {_, v} -> v end)
  |> Enum.sort()
  |> Enum.map(fn {n, vs} -> {n, median.(vs)} end)
end

# The agents do not use the server: their curves are the medians of all twelve runs.
all = Enum.flat_map([0, 1, 2, 4], runs)
guided = %{name: "task agents (guided)", points: curve.(all, "avg_task_ms_agents_guided")}
blind = %{name: "task agents (blind, the thesis's)", points: curve.(all, "avg_task_ms_agents")}

central =
  for s <- [0, 1, 2, 4],
      do: %{name: "central server, #{s} ms a message", points: curve.(runs.(s), "avg_task_ms_central")}

TartarusTools.SVG.write!(
  "docs/warehouse/scaling_server_ms.svg",
  TartarusTools.SVG.line_chart([guided, blind | central],
    title: "Average time per task (20 ms tasks, 10 robots, 5 jobs): agents vs central servers",
    x_label: "tasks per job",
    y_label: "ms per task",
    y_min: 0
  )
)
