defmodule TartarusLats.Report do
  @moduledoc """
  The report of a LATS experiment (`TartarusLats.Experiment`), written into
  the run's directory beside the runner's `summary.json`, `summary.md` and
  series (see `TartarusEmu.Scenario`):

    * `queries.csv` - every query: type, person, start node, world time, whether the
      target was settled then (`TartarusLats.Judge.correct?/4`), answer
      (with its freshness, the age of its evidence, whether it is complete and the
      nodes it could not reach),
      truth, correct (agents, centralized), hops, ms, route;
    * `cloud_connections.csv`, `cloud_connections.svg` - cumulative connections to
      the cloud over world time: centralized (every upload; the CSV also per person),
      agents (contacts of every query, and of the Trace queries about each scripted
      bearer): the thesis's Fig. 3.9; `cloud_connections_agents.svg` - the agents'
      curves alone, on a scale of their own;
    * `rssi.csv`, `rssi.svg` - raw and filtered RSSI of the Janitor's tag at two
      zones, 40 s either side of the Janitor's first hand-over into a zone where it
      then stays 20 s or more, with the thresholds (regions labelled) and the true
      hand-over (Figs. 3.6-3.7);
    * `hops.svg`, `latency.svg` - box plots of query hops and latency per type.
  """

  alias TartarusTools.{Report, SVG}
  alias TartarusLats.{Region, World}

  @typedoc """
  What the report is made of: the experiment's `summary`, its `queries` (one
  map per query), the cloud's `cloud_log`, the recorded `rssi` rows and the
  final `world`.
  """
  @type data :: %{
          summary: map(),
          queries: [map()],
          cloud_log: [map()],
          rssi: [{integer(), map()}],
          world: World.t()
        }

  @doc "Writes the files listed in the moduledoc into `dir`; returns their paths."
  @spec write!(Path.t(), data()) :: [Path.t()]
  def write!(dir, data) do
    File.mkdir_p!(dir)
    world = data.world
    hops = by_type(data.queries, & &1.hops)
    ms = by_type(data.queries, & &1.ms)

    [write_queries(dir, data.queries)] ++
      write_cloud(dir, data, world) ++
      write_rssi(dir, data, world) ++
      [
        SVG.write!(
          Path.join(dir, "hops.svg"),
          SVG.box_plot(hops, title: "Query hops per type (agent design)", y_label: "hops")
        ),
        SVG.write!(
          Path.join(dir, "latency.svg"),
          SVG.box_plot(ms, title: "Query latency per type (agent design)", y_label: "ms")
        )
      ]
  end

  @doc "The \"ours vs the thesis\" rows of `summary.md` for a summary."
  @spec comparisons(map()) :: [Report.comparison()]
  def comparisons(summary) do
    [
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
        metric: "correct, settled / moving targets (agents; centralized)",
        ours:
          "#{summary.correct_settled} / #{summary.correct_moving}; #{summary.correct_settled_centralized} / #{summary.correct_moving_centralized} (#{summary.noise_db} dB noise)",
        thesis: "not reported"
      },
      %{metric: "median query hops", ours: summary.median_query_hops, thesis: "not reported"}
    ]
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
          q.settled,
          show(q.answer),
          show(truth(q)),
          q.correct,
          q.correct_centralized,
          q.hops,
          Float.round(q.ms * 1.0, 3),
          Enum.join(q.route, " "),
          q.time_error,
          q.freshness,
          q.evidence_age_s,
          q.complete,
          Enum.join(q.unreachable, " "),
          q |> Map.get(:breaks, []) |> Enum.map_join(" ", &show_break/1)
        ]
      end)

    Report.write_csv!(
      dir,
      "queries",
      ~w(id type person start time settled answer truth correct correct_centralized hops ms route trace_time_error_s freshness evidence_age_s complete unreachable breaks),
      rows
    )
  end

  # A break of the chain (`TartarusLats.Query.Trace`): `node:kind@t`, then `>node/ring` if
  # it was bridged.
  defp show_break(b) do
    bridged = if b.bridged_to, do: ">#{b.bridged_to}/#{b.ring}", else: ""
    "#{b.node}:#{b.kind}@#{b.at}#{bridged}"
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

    # What each curve counts: every upload; every contact of every query agent; the contacts
    # of the Trace queries about one scripted bearer (the thesis's per-person curves).
    series =
      [{"centralized: every upload", fn e -> e.design == :centralized end}] ++
        [{"agents: contacts of every query", fn e -> e.design == :agents end}] ++
        for name <- scripted, name in queried do
          tag = World.tag(world, name)

          {"agents: contacts of Trace(#{name})",
           fn e -> e.design == :agents and e[:query_type] == :trace and tag in e.tags end}
        end

    per_person =
      for name <- queried do
        tag = World.tag(world, name)

        {"centralized: uploads about #{name}",
         fn e -> e.design == :centralized and tag in e.tags end}
      end

    curves = Enum.map(series ++ per_person, fn {name, f} -> {name, cumulative(log, f)} end)
    seconds = result.summary.world_seconds

    rows =
      for t <- 0..seconds//10 do
        [t | Enum.map(curves, fn {_, pts} -> value_at(pts, t) end)]
      end

    csv =
      Report.write_csv!(
        dir,
        "cloud_connections",
        ["time_s" | Enum.map(curves, &elem(&1, 0))],
        rows
      )

    chart =
      curves
      |> Enum.take(length(series))
      |> Enum.map(fn {name, pts} -> %{name: name, points: step_points(pts, seconds)} end)

    svg =
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

    # The agents' curves on their own scale: beside the centralized one they lie on the axis.
    agents_svg =
      SVG.write!(
        Path.join(dir, "cloud_connections_agents.svg"),
        SVG.line_chart(tl(chart),
          title: "Cloud connections of the query agents alone (scale of their own)",
          x_label: "world time",
          x_unit: "s",
          y_label: "connections",
          markers: false
        )
      )

    [csv, svg, agents_svg]
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

  # The RSSI around one hand-over of the Janitor's (Figs. 3.6-3.7): the first move (after
  # 40 s, within the recorded seconds) into a zone where the Janitor then stays at least
  # 20 s; 40 s either side of it.
  defp write_rssi(dir, result, world) do
    recorded = result.rssi |> Enum.map(&elem(&1, 0)) |> Enum.max(fn -> 0 end)

    with true <- :janitor in World.names(world),
         {a, b, at} <- hand_over(World.visited_path(world, :janitor), recorded - 40) do
      rows =
        for {t, row} <- result.rssi, t >= at - 40 and t <= at + 40 do
          {ra, fa} = row[a]
          {rb, fb} = row[b]
          [t, ra, fa && Float.round(fa, 2), rb, fb && Float.round(fb, 2)]
        end

      csv =
        Report.write_csv!(
          dir,
          "rssi",
          ["time_s", "raw_#{a}", "filtered_#{a}", "raw_#{b}", "filtered_#{b}"],
          rows
        )

      cal = Region.calibrate(tx_power: -59, exponent: world.radio.exponent)
      {lo, hi} = {at - 40, at + 40}
      pick = fn i -> for [t | r] <- rows, v = Enum.at(r, i), is_number(v), do: {t, v} end
      top = rows |> Enum.flat_map(&tl/1) |> Enum.filter(&is_number/1) |> Enum.max(fn -> -50 end)
      near = Float.round(cal.near_dbm, 1)
      far = Float.round(cal.far_dbm, 1)

      svg =
        SVG.write!(
          Path.join(dir, "rssi.svg"),
          SVG.line_chart(
            [
              %{name: "raw at #{a} (left)", points: pick.(0)},
              %{name: "filtered at #{a}", points: pick.(1)},
              %{name: "raw at #{b} (entered)", points: pick.(2)},
              %{name: "filtered at #{b}", points: pick.(3)},
              %{name: "near above #{near} dBm", points: [{lo, cal.near_dbm}, {hi, cal.near_dbm}]},
              %{
                name: "far above #{far} dBm; beyond under",
                points: [{lo, cal.far_dbm}, {hi, cal.far_dbm}]
              },
              %{name: "true hand-over (t = #{at} s)", points: [{at, -100}, {at, max(top, -50)}]}
            ],
            title: "Janitor's tag handed over from #{a} to #{b} (cf. Figs. 3.6-3.7)",
            x_label: "world time",
            x_unit: "s",
            y_label: "RSSI",
            y_unit: "dBm",
            y_min: -100,
            markers: false
          )
        )

      [csv, svg]
    else
      _ -> []
    end
  end

  defp hand_over(path, last) do
    path
    |> Enum.chunk_every(2, 1, :discard)
    |> Enum.find_value(fn [x, y] ->
      stays? = (y.left_at || last) - y.entered_at >= 20

      if stays? and y.entered_at >= 40 and y.entered_at <= last,
        do: {x.zone, y.zone, y.entered_at}
    end)
  end
end
