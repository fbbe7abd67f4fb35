defmodule TartarusEmu.Figures do
  @moduledoc """
  Pictures of the emulator's networks, drawn with `TartarusTools.SVG.plan/2`:

    * `topology/2` - the nodes and links of a `TartarusEmu.Topology` (a grid, a ring, a
      line, a random geometric graph, a floor-plan file);
    * `walk/3` - an agent's walk over it: an arrow per pair of nodes and direction, as thick
      as the agent's hops over it are many, light to dark by time, a start marker where the
      agent was created and an end marker where it stopped.

  Nodes stand at the topology's positions (the first two coordinates); a topology without
  a position for every node is laid out on a circle. Floor plans (files and custom
  topologies) are in metres and get a scale bar; generated topologies are in plot units
  (a grid's spacing is 1) and say so in the footnote. Every node is
  `<circle class="node" data-id="h1" data-x=".." data-y="..">`, every link
  `<polyline class="link" data-a="h1" data-b="h2">` and every arrow of hops
  `<polyline class="hop" data-from="h1" data-to="h2" data-count="2" data-steps="3 8">`, so a
  test can read the drawing back against the topology and the path.

  `mix tartarus.emu` writes both for its run (`topology.svg`, `walk.svg`, the path in
  `walk_path.csv`) when the topology has at most #{2_000} nodes.

      iex> topo = TartarusEmu.Topology.ring(6)
      iex> svg = TartarusEmu.Figures.topology(topo)
      iex> length(Regex.scan(~r/class="node"/, svg)) == 6 and length(Regex.scan(~r/class="link"/, svg)) == 6
      true
  """

  alias TartarusEmu.Topology
  alias TartarusTools.SVG

  @max_nodes 2_000
  @labels_max 64

  @doc "The largest topology (in nodes) the figures draw: #{@max_nodes}."
  @spec max_nodes() :: pos_integer()
  def max_nodes, do: @max_nodes

  @doc """
  `%{node => {x, y}}`: the topology's positions (first two coordinates) when every node has
  one, otherwise the nodes in their order on a unit circle.

      iex> TartarusEmu.Figures.positions(TartarusEmu.Topology.grid(1, 2))
      %{h1: {0.0, 0.0}, h2: {1.0, 0.0}}
  """
  @spec positions(Topology.t()) :: %{term() => {number(), number()}}
  def positions(%Topology{nodes: nodes, positions: pos}) do
    if nodes != [] and Enum.all?(nodes, &Map.has_key?(pos, &1)) do
      Map.new(nodes, fn n -> {n, Tuple.to_list(pos[n]) |> Enum.take(2) |> List.to_tuple()} end)
    else
      count = max(length(nodes), 1)

      nodes
      |> Enum.with_index()
      |> Map.new(fn {n, i} ->
        a = 2 * :math.pi() * i / count
        {n, {:math.cos(a), :math.sin(a)}}
      end)
    end
  end

  @doc """
  An SVG of the topology: links as grey lines, nodes as discs (named when there are at
  most #{@labels_max}). Options: `:title` (default "Topology: <kind>, N nodes, E links"),
  `:subtitle`, `:note`, `:unit` (default `"m"` for files and custom topologies with
  positions, none otherwise).
  """
  @spec topology(Topology.t(), keyword()) :: binary()
  def topology(%Topology{} = topo, opts \\ []) do
    pos = positions(topo)

    SVG.plan(
      base_shapes(topo, pos, "#4e79a7", "#888"),
      [
        title: Keyword.get(opts, :title, default_title(topo)),
        note: Keyword.get(opts, :note, units_note(topo, pos, opts))
      ] ++ plan_opts(topo, opts)
    )
  end

  @doc """
  An SVG of a walk over `topo`: `path` is `[{step, node}]` in time order, its first entry
  the node the agent started on (step 0) and each next one the node a move reached at that
  step; moves that failed leave no hop. Hops between the same two nodes in the same
  direction are one arrow, as thick as they are many (1.5 px for one, 7 px for the most
  travelled pair) and labelled with their count when more than one, coloured by the last
  hop over it, light (early) to dark (late): a walk of 100 hops over 3 hosts draws at most
  6 arrows, not 100 on top of each other. The start is a green disc, the end a red square.
  Each arrow is `<polyline class="hop" data-from="h1" data-to="h2" data-count="3"
  data-steps="2 7 9">`. Options as `topology/2` (the default title is "Walk: ...").
  """
  @spec walk(Topology.t(), [{non_neg_integer(), term()}], keyword()) :: binary()
  def walk(%Topology{} = topo, [{_, start} | _] = path, opts \\ []) do
    pos = positions(topo)
    hops = Enum.zip(path, tl(path))
    count = length(hops)

    # {from, to} => [{hop index, step}], in the order of their first hop.
    pairs =
      hops
      |> Enum.with_index()
      |> Enum.group_by(fn {{{_, a}, {_, b}}, _} -> {a, b} end, fn {{_, {step, _}}, i} ->
        {i, step}
      end)
      |> Enum.sort_by(fn {_, [{i, _} | _]} -> i end)

    most = pairs |> Enum.map(fn {_, hs} -> length(hs) end) |> Enum.max(fn -> 1 end)

    arrows =
      Enum.flat_map(pairs, fn {{a, b}, hs} ->
        {p, q} = offset_segment(pos[a], pos[b])
        {last, _} = List.last(hs)
        n = length(hs)
        shade = if count > 1, do: last / (count - 1), else: 1.0
        width = if most > 1, do: 1.5 + 5.5 * (n - 1) / (most - 1), else: 1.5
        steps = Enum.map_join(hs, " ", &elem(&1, 1))

        arrow = %{
          shape: :line,
          points: [p, q],
          width_px: width,
          arrow: true,
          stroke: ramp(shade),
          class: "hop",
          data: %{from: a, to: b, count: n, steps: steps},
          title: "#{a} -> #{b}: #{hop_words(n)} (steps #{steps})"
        }

        # The count stands beside the arrow's middle, on its right (away from the return).
        {{px, py}, {qx, qy}} = {p, q}
        {mx, my} = {(px + qx) / 2 + (qy - py) * 0.12, (py + qy) / 2 - (qx - px) * 0.12}

        label =
          if n > 1,
            do: [%{shape: :text, x: mx, y: my, text: "#{n}", size: 10, class: "hop-count"}],
            else: []

        [arrow | label]
      end)

    {_, stop} = List.last(path)
    {sx, sy} = pos[start]
    {ex, ey} = pos[stop]

    markers = [
      %{
        shape: :marker,
        kind: :start,
        x: sx,
        y: sy,
        title: "start: #{start}",
        data: %{node: start}
      },
      %{shape: :marker, kind: :end, x: ex, y: ey, title: "end: #{stop}", data: %{node: stop}}
    ]

    SVG.plan(
      base_shapes(topo, pos, "#c9d3df", "#d5d5d5") ++ arrows ++ markers,
      [
        title: Keyword.get(opts, :title, "Walk: #{count} hops over #{default_title(topo, "")}"),
        note:
          Keyword.get(
            opts,
            :note,
            "arrows: hops per pair and direction (width, number), " <>
              "light to dark by the last one's time; " <>
              units_note(topo, pos, opts)
          ),
        legend: [
          {"start (#{start})", "#2ca02c", :start},
          {"end (#{stop})", "#d62728", :end},
          {"early", ramp(0.0), :line},
          {"late", ramp(1.0), :line}
        ]
      ] ++ plan_opts(topo, opts)
    )
  end

  defp plan_opts(topo, opts) do
    [
      subtitle: Keyword.get(opts, :subtitle),
      unit: Keyword.get(opts, :unit, default_unit(topo))
    ]
  end

  defp base_shapes(topo, pos, node_colour, link_colour) do
    labels? = length(topo.nodes) <= @labels_max
    r = if length(topo.nodes) > 400, do: 2, else: 5

    links =
      for {a, b} <- Enum.sort(topo.edges) do
        %{
          shape: :line,
          points: [pos[a], pos[b]],
          width_px: 1.5,
          stroke: link_colour,
          class: "link",
          data: %{a: a, b: b}
        }
      end

    nodes =
      for n <- topo.nodes do
        {x, y} = pos[n]

        %{shape: :circle, x: x, y: y, r_px: r, fill: node_colour, stroke: "#234", class: "node"}
        |> Map.put(:data, %{id: n})
        |> Map.put(:title, to_string(n))
        |> then(&if labels?, do: Map.put(&1, :label, to_string(n)), else: &1)
      end

    links ++ nodes
  end

  defp default_title(topo, prefix \\ "Topology: ") do
    "#{prefix}#{topo.kind}, #{Topology.size(topo)} nodes, #{Topology.edge_count(topo)} links"
  end

  defp default_unit(%Topology{kind: kind, positions: pos}) when kind in [:file, :custom] do
    if map_size(pos) > 0, do: "m"
  end

  defp default_unit(_topo), do: nil

  defp units_note(topo, _pos, opts) do
    cond do
      Keyword.get(opts, :unit, default_unit(topo)) ->
        "positions in metres"

      not Enum.all?(topo.nodes, &Map.has_key?(topo.positions, &1)) ->
        "nodes on a circle (no positions)"

      true ->
        "positions in plot units (#{plot_units(topo.kind)})"
    end
  end

  defp plot_units(:grid), do: "the grid's spacing is 1"
  defp plot_units(:line), do: "the spacing is 1"
  defp plot_units(:ring), do: "the ring's radius is 1"
  defp plot_units(:random_geometric), do: "nodes drawn in the unit square"
  defp plot_units(_), do: "no scale"

  defp hop_words(1), do: "1 hop"
  defp hop_words(n), do: "#{n} hops"

  # The segment a -> b, shortened at both ends and moved a little to its right, so that a
  # hop back along the same link is drawn beside the hop out, and arrowheads stop short of
  # the nodes.
  defp offset_segment({xa, ya}, {xb, yb}) do
    {dx, dy} = {xb - xa, yb - ya}
    len = :math.sqrt(dx * dx + dy * dy)

    if len == 0 do
      {{xa, ya}, {xb, yb}}
    else
      {ox, oy} = {dy / len * len * 0.06, -dx / len * len * 0.06}
      {{xa + dx * 0.15 + ox, ya + dy * 0.15 + oy}, {xb - dx * 0.15 + ox, yb - dy * 0.15 + oy}}
    end
  end

  # Light orange (0.0) to dark red-brown (1.0).
  defp ramp(f) do
    {r, g, b} = {round(253 - 150 * f), round(174 - 150 * f), round(97 - 80 * f)}
    "#" <> Enum.map_join([r, g, b], &String.pad_leading(Integer.to_string(&1, 16), 2, "0"))
  end
end
