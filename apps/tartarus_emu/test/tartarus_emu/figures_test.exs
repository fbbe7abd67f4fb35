defmodule TartarusEmu.FiguresTest do
  use ExUnit.Case, async: true

  alias TartarusEmu.{Figures, Scenario, Topology, Walk}

  doctest Figures

  defp tmp do
    dir = Path.join(System.tmp_dir!(), "emu_figures_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    dir
  end

  # Each element of `class` as a map of its attributes (names without "data-" for data-*).
  defp elements(svg, tag, class) do
    for [attrs] <-
          Regex.scan(~r/<#{tag} ([^>]*class="#{class}"[^>]*)>/, svg, capture: :all_but_first) do
      Map.new(Regex.scan(~r/([\w-]+)="([^"]*)"/, attrs), fn [_, k, v] ->
        {String.replace_prefix(k, "data-", ""), v}
      end)
    end
  end

  defp float(v), do: elem(Float.parse(v), 0)

  defp px_per_unit(svg),
    do: float(hd(Regex.run(~r/data-px-per-unit="([^"]+)"/, svg, capture: :all_but_first)))

  test "a topology figure: a disc per node at its position, a line per link, one scale for both axes" do
    topo = Topology.grid(3, 4)
    svg = Figures.topology(topo, subtitle: "grid, seed 1")
    nodes = elements(svg, "circle", "node")
    assert Enum.map(nodes, & &1["id"]) == Enum.map(topo.nodes, &to_string/1)

    for n <- nodes do
      {x, y} = topo.positions[String.to_atom(n["id"])]
      assert {float(n["x"]), float(n["y"])} == {x, y}
    end

    links = for l <- elements(svg, "polyline", "link"), do: {l["a"], l["b"]}

    assert Enum.sort(links) ==
             Enum.sort(for {a, b} <- topo.edges, do: {to_string(a), to_string(b)})

    # pixels: h1 (0, 0) and h4 (3, 0) are 3 units apart, h1 and h9 (0, 2) 2 units apart
    px = Map.new(nodes, &{&1["id"], {float(&1["cx"]), float(&1["cy"])}})
    k = px_per_unit(svg)
    assert_in_delta elem(px["h4"], 0) - elem(px["h1"], 0), 3 * k, 0.02
    assert_in_delta elem(px["h1"], 1) - elem(px["h9"], 1), 2 * k, 0.02
    assert svg =~ "Topology: grid, 12 nodes, 17 links" and svg =~ "grid, seed 1"
    # plot units: no scale bar, and the footnote says so
    refute svg =~ "scale-bar"
    assert svg =~ "positions in plot units"
  end

  test "a floor plan in metres gets a scale bar that measures its positions" do
    {:ok, topo} =
      Topology.parse("""
      node lobby 0 0
      node lab 4.5 0
      node stairs 4.5 3
      edge lobby lab
      edge lab stairs
      """)

    svg = Figures.topology(topo)
    [bar] = elements(svg, "g", "scale-bar")
    assert bar["unit"] == "m"
    k = px_per_unit(svg)
    assert_in_delta float(bar["px"]), float(bar["length"]) * k, 0.02
    px = Map.new(elements(svg, "circle", "node"), &{&1["id"], float(&1["cx"])})
    assert_in_delta px["lab"] - px["lobby"], 4.5 * k, 0.02
  end

  test "walk.svg draws the first agent's walk of walk_path.csv hop by hop, each hop a link" do
    dir = tmp()

    {:ok, %{summary: s}} =
      Scenario.run(Walk,
        topology: "ring",
        hosts: 10,
        agents: 3,
        steps: 25,
        seed: 3,
        out: dir,
        quiet: true
      )

    [_ | rows] =
      dir |> Path.join("walk_path.csv") |> File.read!() |> String.split("\n", trim: true)

    path = for r <- rows, [k, n] = String.split(r, ","), do: {String.to_integer(k), n}
    assert hd(path) |> elem(0) == 0
    svg = File.read!(Path.join(dir, "walk.svg"))
    {:ok, topo} = Walk.topology(%{topology: "ring", hosts: 10})
    edges = MapSet.new(topo.edges, fn {a, b} -> Enum.sort([to_string(a), to_string(b)]) end)

    arrows = elements(svg, "polyline", "hop")

    hops =
      Enum.sort(
        for h <- arrows,
            k <- String.split(h["steps"]),
            do: {String.to_integer(k), h["from"], h["to"]}
      )

    assert hops ==
             for({{_, a}, {k, b}} <- Enum.zip(path, tl(path)), do: {k, a, b})

    # one arrow per pair and direction, counting its hops
    assert length(arrows) == length(Enum.uniq_by(arrows, &{&1["from"], &1["to"]}))
    for h <- arrows, do: assert(String.to_integer(h["count"]) == length(String.split(h["steps"])))

    # no failures on a static ring: a hop at every step; every hop along a link
    assert length(hops) == s.steps
    for {_, a, b} <- hops, do: assert(MapSet.member?(edges, Enum.sort([a, b])))

    [start] = elements(svg, "circle", "start")
    [stop] = elements(svg, "rect", "end")
    assert start["node"] == elem(hd(path), 1)
    assert stop["node"] == elem(List.last(path), 1)
    {x, y} = topo.positions[String.to_atom(stop["node"])]
    assert_in_delta float(stop["x"]), x, 1.0e-4
    assert_in_delta float(stop["y"]), y, 1.0e-4
    assert svg =~ "Walk of agent 1: #{length(hops)} hops in #{s.steps} steps"
    assert svg =~ "ring, 10 hosts, 3 agents, random, p 0, seed 3"
    assert File.exists?(Path.join(dir, "topology.svg"))
  end

  test "a long walk over 3 hosts: an arrow per pair and direction, as thick as its hops are many" do
    topo = Topology.line(3)
    # 100 hops back and forth along h1 - h2 - h3.
    nodes = Stream.cycle([:h1, :h2, :h3, :h2]) |> Enum.take(101)
    path = Enum.with_index(nodes, fn n, k -> {k, n} end)
    svg = Figures.walk(topo, path)
    arrows = elements(svg, "polyline", "hop")

    counts = Map.new(arrows, &{{&1["from"], &1["to"]}, String.to_integer(&1["count"])})

    assert counts == %{
             {"h1", "h2"} => 25,
             {"h2", "h3"} => 25,
             {"h3", "h2"} => 25,
             {"h2", "h1"} => 25
           }

    # equal counts, equal widths (the widest); a pair walked less is thinner
    widths = Enum.map(arrows, &float(&1["stroke-width"]))
    assert Enum.uniq(widths) == [7.0]

    uneven = Figures.walk(topo, Enum.with_index([:h1, :h2, :h1, :h2, :h3], fn n, k -> {k, n} end))
    by_pair = Map.new(elements(uneven, "polyline", "hop"), &{{&1["from"], &1["to"]}, &1})

    assert by_pair[{"h1", "h2"}]["count"] == "2" and
             float(by_pair[{"h1", "h2"}]["stroke-width"]) == 7.0

    assert by_pair[{"h2", "h3"}]["count"] == "1" and
             float(by_pair[{"h2", "h3"}]["stroke-width"]) == 1.5

    # the count of a pair walked more than once is written beside its arrow
    assert Regex.scan(~r/<text[^>]*class="hop-count"[^>]*>(\d+)</, uneven, capture: :all_but_first) ==
             [["2"]]

    assert svg =~ "arrows: hops per pair and direction (width, number)"
  end

  test "coverage.svg shows coverage.csv's numbers, on an axis from 0 to 1, with the run's parameters" do
    dir = tmp()

    {:ok, _} =
      Scenario.run(Walk,
        topology: "grid",
        hosts: 9,
        agents: 1,
        steps: 12,
        seed: 2,
        out: dir,
        quiet: true
      )

    [_ | rows] =
      dir |> Path.join("coverage.csv") |> File.read!() |> String.split("\n", trim: true)

    csv = for r <- rows, [k, v] = String.split(r, ","), do: {String.to_integer(k), float(v)}
    svg = File.read!(Path.join(dir, "coverage.svg"))

    drawn =
      for [x, y] <-
            Regex.scan(~r/<title>coverage: \(([^,]+), ([^)]+)\)<\/title>/, svg,
              capture: :all_but_first
            ),
          do: {String.to_integer(x), float(y)}

    assert length(drawn) == length(csv)
    for {{k, v}, {dk, dv}} <- Enum.zip(csv, drawn), do: assert(k == dk and abs(v - dv) < 1.0e-4)

    ticks =
      for [v] <- Regex.scan(~r/text-anchor="end">([^<]+)<\/text>/, svg, capture: :all_but_first),
          do: v

    assert hd(ticks) == "0" and List.last(ticks) == "1"
    assert svg =~ "hosts visited (fraction of all hosts)"
    assert svg =~ "grid, 9 hosts, 1 agent, random, p 0, seed 2"
  end
end
