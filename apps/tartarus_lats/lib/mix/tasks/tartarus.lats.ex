defmodule Mix.Tasks.Tartarus.Lats do
  @shortdoc "LATS: agent queries vs the cloud baseline on an emulated building (thesis ch. 3)"
  @moduledoc """
  Runs the LATS comparison of the thesis (§3.4): the centralized cloud design
  and the mobile-agent design on the same emulated building, world and
  queries (see `TartarusLats.Experiment`).

      mix tartarus.lats [--nodes 50] [--bearers 10] [--minutes 20] [--queries 30]
                        [--mode virtual|peer] [--group 10] --seed S --out DIR [--json]

  Writes into `--out DIR` (default `runs/lats-<timestamp>`):

    * `queries.csv` - every query: type, person, start node, world time, answer,
      truth, correct (agents, centralized), hops, ms, route;
    * `cloud_connections.csv`, `cloud_connections.svg` - cumulative connections to
      the cloud over world time: centralized (all uploads, and per person),
      agents (all, and per queried person): the thesis's Fig. 3.9;
    * `rssi.csv`, `rssi.svg` - raw and filtered RSSI of the Janitor's tag at the
      first two zones of the Janitor's path, with the near/far thresholds
      (Fig. 3.6/3.7);
    * `hops.svg`, `latency.svg` - box plots of query hops and latency per type;
    * `summary.json`, `summary.md` - the keys below, and ours vs the thesis.

  Summary keys: `queries, correct, correct_centralized,
  cloud_connections_centralized, cloud_connections_agents, cloud_connection_ratio,
  cloud_bytes_centralized, cloud_bytes_agents, median_query_hops, max_query_hops,
  median_query_ms, trace_time_error_s, by_type, nodes, bearers, minutes, seed, mode,
  world_seconds, wall_ms`. With `--json` the last line printed is the summary as one
  JSON object.
  """
  use TartarusTools.CLI

  alias TartarusTools.{Report, SVG}
  alias TartarusLats.{Experiment, Region, World}

  @switches [
    nodes: :integer,
    bearers: :integer,
    minutes: :integer,
    queries: :integer,
    mode: :string,
    group: :integer,
    seed: :integer,
    out: :string,
    json: :boolean
  ]

  @impl true
  def run(argv) do
    opts = TartarusTools.CLI.parse!(argv, @switches, "tartarus.lats")

    TartarusTools.CLI.positive!(
      opts,
      [:nodes, :bearers, :minutes, :queries, :group],
      "tartarus.lats"
    )

    if (opts[:nodes] || 50) < 10,
      do: Mix.raise("mix tartarus.lats: --nodes must be at least 10, got: #{opts[:nodes]}")

    mode =
      TartarusTools.CLI.choice!(opts[:mode], [:virtual, :peer], :mode, "tartarus.lats", :virtual)

    Mix.Task.run("app.start")
    dir = opts[:out] || Report.default_out_dir("lats")
    seed = opts[:seed] || 1

    unless opts[:json],
      do: Mix.shell().info("LATS: #{opts[:nodes] || 50} nodes, seed #{seed}, #{mode} hosts...")

    result =
      Experiment.run(
        nodes: opts[:nodes] || 50,
        bearers: opts[:bearers] || 10,
        minutes: opts[:minutes] || 20,
        queries: opts[:queries] || 30,
        seed: seed,
        mode: mode,
        group: opts[:group] || 10,
        progress: if(opts[:json], do: false, else: [])
      )

    write_report(dir, result)
    summary = result.summary

    if opts[:json] do
      Mix.shell().info(TartarusTools.JSON.encode!(summary))
    else
      Mix.shell().info("""
      queries: #{summary.queries}, correct: #{summary.correct} (centralized: #{summary.correct_centralized})
      cloud connections: centralized #{summary.cloud_connections_centralized}, agents #{summary.cloud_connections_agents} (ratio #{summary.cloud_connection_ratio})
      cloud bytes: centralized #{summary.cloud_bytes_centralized}, agents #{summary.cloud_bytes_agents}
      median query hops #{summary.median_query_hops}, median latency #{summary.median_query_ms} ms
      written to #{dir}\
      """)
    end
  end

  @doc false
  def write_report(dir, %{summary: summary} = result) do
    File.mkdir_p!(dir)
    world = result.meta.world
    write_queries(dir, result.queries)
    write_cloud(dir, result, world)
    write_rssi(dir, result, world)

    hops = by_type(result.queries, & &1.hops)
    ms = by_type(result.queries, & &1.ms)

    SVG.write!(
      Path.join(dir, "hops.svg"),
      SVG.box_plot(hops, title: "Query hops per type (agent design)", y_label: "hops")
    )

    SVG.write!(
      Path.join(dir, "latency.svg"),
      SVG.box_plot(ms, title: "Query latency per type (agent design)", y_label: "ms")
    )

    Report.write_summary!(dir, stringify(summary),
      title: "LATS (thesis ch. 3): agents vs cloud",
      comparisons: [
        %{
          metric: "cloud connections, agents / centralized",
          ours:
            "#{summary.cloud_connections_agents} / #{summary.cloud_connections_centralized} (#{summary.cloud_connection_ratio})",
          thesis: "agents far fewer (Fig. 3.9; no totals printed)"
        },
        %{
          metric: "correct answers (agents)",
          ours: "#{summary.correct}/#{summary.queries}",
          thesis: "not reported"
        },
        %{
          metric: "median query hops",
          ours: summary.median_query_hops,
          thesis: "not reported"
        }
      ]
    )
  end

  defp stringify(summary) do
    Map.new(summary, fn
      {:by_type, v} -> {:by_type, Map.new(v, fn {k, m} -> {to_string(k), m} end)}
      {k, v} when is_atom(v) and not is_nil(v) and not is_boolean(v) -> {k, to_string(v)}
      kv -> kv
    end)
  end

  defp by_type(queries, fun) do
    for type <- [:where_am_i, :where_is, :trace] do
      {type, queries |> Enum.filter(&(&1.type == type)) |> Enum.map(fun)}
    end
  end

  defp write_queries(dir, queries) do
    rows =
      Enum.map(queries, fn q ->
        [
          q.id,
          q.type,
          q.person,
          q.start,
          q.time,
          show(q.answer),
          show(truth(q)),
          q.correct,
          q.correct_centralized,
          q.hops,
          Float.round(q.ms * 1.0, 3),
          Enum.join(q.route, " "),
          q.time_error
        ]
      end)

    Report.write_csv!(
      dir,
      "queries",
      ~w(id type person start time answer truth correct correct_centralized hops ms route trace_time_error_s),
      rows
    )
  end

  defp truth(%{type: :trace, truth: t}), do: {t.zones, t.status}
  defp truth(q), do: q.truth

  defp show({:ok, %{path: path, status: status}}),
    do: "#{Enum.map_join(path, ">", & &1.node)} (#{status})"

  defp show({zones, status}) when is_list(zones), do: "#{Enum.join(zones, ">")} (#{status})"
  defp show({:in_zone, z}), do: "in_zone #{z}"
  defp show(other), do: inspect(other)

  defp write_cloud(dir, result, world) do
    log = result.cloud_log
    queried = result.queries |> Enum.map(& &1.person) |> Enum.uniq()
    scripted = Enum.filter(World.names(world), &(Map.fetch!(world.bearers, &1).kind == :scripted))

    series =
      [{"centralized (all)", fn e -> e.design == :centralized end}] ++
        [{"agents (all queries)", fn e -> e.design == :agents end}] ++
        for name <- scripted, name in queried do
          tag = World.tag(world, name)
          {"agents: #{name}", fn e -> e.design == :agents and tag in e.tags end}
        end

    per_person =
      for name <- queried do
        tag = World.tag(world, name)
        {"centralized: #{name}", fn e -> e.design == :centralized and tag in e.tags end}
      end

    curves = Enum.map(series ++ per_person, fn {name, f} -> {name, cumulative(log, f)} end)
    seconds = result.summary.world_seconds

    rows =
      for t <- 0..seconds//10 do
        [t | Enum.map(curves, fn {_, pts} -> value_at(pts, t) end)]
      end

    Report.write_csv!(dir, "cloud_connections", ["time_s" | Enum.map(curves, &elem(&1, 0))], rows)

    chart =
      curves
      |> Enum.take(length(series))
      |> Enum.map(fn {name, pts} -> %{name: name, points: step_points(pts, seconds)} end)

    SVG.write!(
      Path.join(dir, "cloud_connections.svg"),
      SVG.line_chart(chart,
        title: "Cumulative connections to the cloud (cf. thesis Fig. 3.9)",
        x_label: "world time",
        x_unit: "s",
        y_label: "connections",
        markers: false
      )
    )
  end

  defp cumulative(log, f) do
    log
    |> Enum.filter(f)
    |> Enum.map(& &1.time)
    |> Enum.sort()
    |> Enum.with_index(1)
    |> Enum.map(fn {t, n} -> {t, n} end)
  end

  defp value_at(points, t) do
    points
    |> Enum.take_while(fn {pt, _} -> pt <= t end)
    |> List.last()
    |> then(&if(&1, do: elem(&1, 1), else: 0))
  end

  defp step_points(points, seconds) do
    last = Map.new(points)
    pts = Enum.sort(last)
    [{0, 0} | pts] ++ [{seconds, if(pts == [], do: 0, else: elem(List.last(pts), 1))}]
  end

  defp write_rssi(dir, result, world) do
    with true <- :janitor in World.names(world),
         [%{zone: a}, %{zone: b} | _] <- World.visited_path(world, :janitor) do
      rows =
        for {t, row} <- result.rssi do
          {ra, fa} = row[a]
          {rb, fb} = row[b]
          [t, ra, fa && Float.round(fa, 2), rb, fb && Float.round(fb, 2)]
        end

      Report.write_csv!(
        dir,
        "rssi",
        ["time_s", "raw_#{a}", "filtered_#{a}", "raw_#{b}", "filtered_#{b}"],
        rows
      )

      cal = Region.calibrate(tx_power: -59, exponent: world.radio.exponent)
      last = rows |> Enum.map(&hd/1) |> Enum.max(fn -> 1 end)
      pick = fn i -> for [t | r] <- rows, v = Enum.at(r, i), is_number(v), do: {t, v} end

      SVG.write!(
        Path.join(dir, "rssi.svg"),
        SVG.line_chart(
          [
            %{name: "raw at #{a}", points: pick.(0)},
            %{name: "filtered at #{a}", points: pick.(1)},
            %{name: "raw at #{b}", points: pick.(2)},
            %{name: "filtered at #{b}", points: pick.(3)},
            %{name: "near threshold", points: [{0, cal.near_dbm}, {last, cal.near_dbm}]},
            %{name: "far threshold", points: [{0, cal.far_dbm}, {last, cal.far_dbm}]}
          ],
          title: "Janitor's tag: raw and filtered RSSI at #{a} and #{b} (cf. Fig. 3.6/3.7)",
          x_label: "world time",
          x_unit: "s",
          y_label: "RSSI",
          y_unit: "dBm",
          markers: false
        )
      )
    else
      _ -> :ok
    end
  end
end
