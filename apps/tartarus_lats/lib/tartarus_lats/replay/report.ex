defmodule TartarusLats.Replay.Report do
  @moduledoc """
  The files of a real-data replay (`mix tartarus.lats --replay-log`): per track

    * `<track>_seconds.csv` - every second: true position, true zone, and the decisions of
      LATS, the thesis's own rule (an arm, `TartarusLats.Replay`), the strongest-receiver baseline and the fingerprinting baseline;
    * `<track>_queries.csv` - every query (all seeds): seed, type, second, start node, the
      truth, and per design the answer and its judgement (Where is X correct; Trace edit
      distance);
    * `<track>.svg` - the floor plan (receivers, their Delaunay neighbours, the true track)
      with LATS's decision of every second drawn as a line from the true position to the
      deciding receiver (green: the true zone, orange: a neighbour of it, red: neither),
      and under it the zones over time: truth, LATS, the thesis's rule, strongest receiver, fingerprinting.

  Plain functions of a run's result (`TartarusLats.Replay.run/2`) and its case
  (`TartarusLats.Replay.prepare/3`).
  """

  alias TartarusLats.Building
  alias TartarusTools.Report

  @designs [:lats, :thesis, :strongest, :knn]

  # Fingerprinting runs only with --fingerprints: without them the legend says so.
  defp knn_legend(%{knn: %{} = knn}),
    do: "fingerprinting #{pct(knn[:exact])} / #{pct(knn[:adjacent])}"

  defp knn_legend(_summary), do: "fingerprinting not run (no --fingerprints)"

  defp thesis_legend(%{thesis: %{} = t}),
    do: "thesis's rule #{pct(t[:exact])} / #{pct(t[:adjacent])}; "

  defp thesis_legend(_summary), do: ""

  @doc "Writes a track's files into `dir`; returns their paths."
  @spec write!(Path.t(), map(), [map()]) :: [Path.t()]
  def write!(dir, c, results) do
    File.mkdir_p!(dir)
    first = hd(results)
    # The designs judged in this run (no fingerprinting without reference points: no column).
    designs = Enum.filter(@designs, &Map.has_key?(first.summary, &1))

    seconds =
      Report.write_csv!(
        dir,
        "#{c.name}_seconds.csv",
        ~w(second x y truth) ++ Enum.map(designs, &Atom.to_string/1),
        for r <- first.seconds do
          {x, y} = Map.get(c.positions, r.second, {nil, nil})
          [r.second, x, y, r.truth] ++ Enum.map(designs, &Map.get(r, &1))
        end
      )

    queries =
      Report.write_csv!(
        dir,
        "#{c.name}_queries.csv",
        ~w(seed type second start truth) ++
          Enum.flat_map(designs, &["#{&1}_answer", "#{&1}_judged"]) ++
          ~w(lats_hops lats_cloud_contacts),
        for r <- results, q <- r.queries do
          [r.summary.seed, q.type, q.time, q.start, Enum.join(q.truth, " ")] ++
            Enum.flat_map(designs, fn d ->
              case q.judged[d] do
                nil -> [nil, nil]
                j -> [show(j.answer), Map.get(j, :correct, Map.get(j, :edit_distance))]
              end
            end) ++ [q.hops, q.result.per_node_contacts]
        end
      )

    svg = Path.join(dir, "#{c.name}.svg")
    File.write!(svg, svg(c, first))
    [seconds, queries, svg]
  end

  defp show({:in_zone, z}), do: "in_zone #{z}"
  defp show(list) when is_list(list), do: Enum.join(list, " ")
  defp show(other), do: inspect(other)

  @doc "The track's figure (see the moduledoc) as an SVG document."
  @spec svg(map(), map()) :: String.t()
  def svg(c, result) do
    b = c.building
    nodes = Building.nodes(b)
    {w, margin, scale} = {760, 40, 30}

    {xs, ys} =
      nodes
      |> Enum.map(&Building.position(b, &1))
      |> Enum.map(&{elem(&1, 0), elem(&1, 1)})
      |> Enum.unzip()

    {x0, y0} = {min(Enum.min(xs), 0.0), min(Enum.min(ys), 0.0)}
    plan_h = (Enum.max(ys) - y0 + 1) * scale
    px = fn x -> margin + (x - x0) * scale end
    py = fn y -> margin + 30 + plan_h - (y - y0) * scale end
    at = fn n -> Building.position(b, n) |> then(&{px.(elem(&1, 0)), py.(elem(&1, 1))}) end

    edges =
      for n <- nodes, m <- Building.neighbours(b, n), n < m do
        {ax, ay} = at.(n)
        {bx, by} = at.(m)
        line(ax, ay, bx, by, "#ddd", 1)
      end

    decisions =
      for r <- result.seconds, pos = c.positions[r.second], r.lats != nil do
        {x, y} = pos
        {nx, ny} = at.(r.lats)

        colour =
          cond do
            r.lats == r.truth -> "#59a14f"
            r.truth != nil and r.lats in Building.neighbours(b, r.truth) -> "#f28e2b"
            true -> "#e15759"
          end

        line(px.(x), py.(y), nx, ny, colour, 0.8)
      end

    track =
      c.positions
      |> Enum.sort()
      |> Enum.map_join(" ", fn {_s, {x, y}} -> "#{f(px.(x))},#{f(py.(y))}" end)

    receivers =
      for n <- nodes do
        {x, y} = at.(n)

        ~s(<circle cx="#{f(x)}" cy="#{f(y)}" r="5" fill="#4e79a7"/>) <>
          text(x + 7, y - 4, n, 11)
      end

    # The timeline: one row per zone, seconds along x.
    t_top = py.(y0) + 60
    row = 14
    t_left = margin + 70
    t_w = w - t_left - margin
    last = max(length(result.seconds), 1)
    tx = fn s -> t_left + (s - 1) * t_w / max(last - 1, 1) end
    idx = Map.new(Enum.with_index(nodes), fn {n, i} -> {n, i} end)
    ty = fn n -> t_top + 20 + idx[n] * row end

    rows =
      for n <- nodes do
        line(t_left, ty.(n), t_left + t_w, ty.(n), "#eee", 1) <> text(margin, ty.(n) + 4, n, 10)
      end

    marks =
      for r <- result.seconds,
          {d, dy, colour, size} <- [
            {:truth, 0, "#bbb", 6},
            {:lats, -3, "#4e79a7", 3},
            {:thesis, -5, "#59a14f", 1.5},
            {:strongest, 3, "#f28e2b", 2},
            {:knn, 5, "#b07aa1", 1.5}
          ],
          z = Map.get(r, d),
          z != nil do
        ~s(<circle cx="#{f(tx.(r.second))}" cy="#{f(ty.(z) + dy)}" r="#{size}" fill="#{colour}"/>)
      end

    t_bottom = t_top + 30 + length(nodes) * row

    s = result.summary

    legend =
      "LATS exact #{pct(s.lats.exact)} / adjacent #{pct(s.lats.adjacent)}; #{thesis_legend(s)}strongest #{pct(s.strongest.exact)} / #{pct(s.strongest.adjacent)}; #{knn_legend(s)}"

    [
      ~s(<?xml version="1.0" encoding="UTF-8"?>\n),
      ~s(<svg xmlns="http://www.w3.org/2000/svg" width="#{w}" height="#{f(t_bottom + 40)}" viewBox="0 0 #{w} #{f(t_bottom + 40)}">),
      "<title>LATS on #{esc(c.name)}</title>",
      ~s(<rect width="#{w}" height="#{f(t_bottom + 40)}" fill="white"/>),
      text(margin, 22, "LATS on a real recording: #{c.name} (#{result.summary.seconds} s)", 15),
      text(margin, 40, legend, 11),
      edges,
      decisions,
      ~s(<polyline points="#{track}" fill="none" stroke="#333" stroke-width="1.5"/>),
      receivers,
      text(
        margin,
        t_top,
        "zones over time (s): grey truth, blue LATS, green the thesis's rule, orange strongest receiver, purple fingerprinting",
        11
      ),
      rows,
      marks,
      text(t_left, t_bottom + 5, "1", 10),
      text(t_left + t_w - 20, t_bottom + 5, "#{last}", 10),
      text(
        margin,
        t_bottom + 25,
        "Data: F. S. Daniş, A. T. Naskali, A. T. Cemgil, C. Ersoy (Boğaziçi University), CC0. Lines: true position -> LATS's zone (green exact, orange adjacent, red other).",
        9
      ),
      "</svg>\n"
    ]
    |> IO.iodata_to_binary()
  end

  defp pct(nil), do: "-"
  defp pct(x), do: "#{Float.round(x * 100, 1)} %"

  defp line(x1, y1, x2, y2, colour, width),
    do:
      ~s(<line x1="#{f(x1)}" y1="#{f(y1)}" x2="#{f(x2)}" y2="#{f(y2)}" stroke="#{colour}" stroke-width="#{width}"/>)

  defp text(x, y, s, size),
    do:
      ~s(<text x="#{f(x)}" y="#{f(y)}" font-family="sans-serif" font-size="#{size}">#{esc(to_string(s))}</text>)

  defp f(x), do: :erlang.float_to_binary(x * 1.0, decimals: 1)

  defp esc(s),
    do:
      s
      |> String.replace("&", "&amp;")
      |> String.replace("<", "&lt;")
      |> String.replace(">", "&gt;")
end
