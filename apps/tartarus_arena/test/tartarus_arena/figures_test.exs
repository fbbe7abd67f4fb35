defmodule TartarusArena.FiguresTest do
  # The arena's figures read back: trajectories, markers, the scale bar and the labels.
  use ExUnit.Case, async: true

  alias TartarusArena.{Render, World}

  defp elements(svg, tag, class) do
    for [attrs] <-
          Regex.scan(~r/<#{tag} ([^>]*class="#{class}"[^>]*)>/, svg, capture: :all_but_first) do
      Map.new(Regex.scan(~r/([\w-]+)="([^"]*)"/, attrs), fn [_, k, v] ->
        {String.replace_prefix(k, "data-", ""), v}
      end)
    end
  end

  defp float(v), do: elem(Float.parse(v), 0)

  defp world do
    TartarusArena.paths_world(1)
    |> World.add_robot(:r1, x: 0.9, y: 0.3)
    |> World.add_puck(:p7, x: 2.0, y: 2.0)
    |> World.add_puck(:roadblock, x: 1.2, y: 0.3, radius: 0.05, colour: 2, tall: true)
    |> World.set_light(:on)
  end

  test "trajectories: each drawn from its first to its last point, in metres, with a scale bar" do
    a = for i <- 0..20, do: {i * 0.1, 0.5 + i * 0.05, 0.4}
    b = for i <- 0..10, do: {i * 0.1, 2.5, 0.5 + i * 0.2}

    svg =
      Render.trajectories(world(), %{"path 1 (A4)" => a, "path 2 (A4)" => b},
        title: "A4: 2 laps",
        subtitle: "PFA A4, 2 laps, seed 5"
      )

    assert svg =~ "A4: 2 laps" and svg =~ "PFA A4, 2 laps, seed 5"
    k = float(hd(Regex.run(~r/data-px-per-unit="([^"]+)"/, svg, capture: :all_but_first)))
    [bar] = elements(svg, "g", "scale-bar")
    assert bar["unit"] == "m"
    assert_in_delta float(bar["px"]), float(bar["length"]) * k, 0.02
    # the floor is 3 m wide
    [floor] = elements(svg, "rect", "floor")
    assert_in_delta float(floor["width"]), 3.0 * k, 0.02

    lines = elements(svg, "polyline", "trajectory")

    assert Enum.map(lines, &{&1["name"], String.to_integer(&1["samples"])}) == [
             {"path 1 (A4)", 21},
             {"path 2 (A4)", 11}
           ]

    for {line, pts} <- Enum.zip(lines, [a, b]) do
      drawn =
        line["points"]
        |> String.split(" ")
        |> Enum.map(fn p -> p |> String.split(",") |> Enum.map(&float/1) end)

      assert length(drawn) == length(pts)
      # consecutive points: drawn displacement = world displacement times the scale (y flipped)
      for {[x0, y0], [x1, y1], {_, wx0, wy0}, {_, wx1, wy1}} <-
            Enum.zip([drawn, tl(drawn), pts, tl(pts)]) do
        assert_in_delta x1 - x0, (wx1 - wx0) * k, 0.02
        assert_in_delta y0 - y1, (wy1 - wy0) * k, 0.02
      end
    end

    starts = for s <- elements(svg, "circle", "start"), do: {float(s["x"]), float(s["y"])}
    ends = for e <- elements(svg, "rect", "end"), do: {float(e["x"]), float(e["y"])}
    assert starts == [{0.5, 0.4}, {2.5, 0.5}]
    assert ends == [{1.5, 0.4}, {2.5, 2.5}]
  end

  test "objects are labelled: the light, the pucks and blocks, the markers; robots by id" do
    svg = Render.svg(world(), subtitle: "seed 1")

    labels =
      for [l] <- Regex.scan(~r/<text class="label"[^>]*>([^<]+)</, svg, capture: :all_but_first),
          do: l

    assert "light (on)" in labels
    assert "puck p7" in labels
    assert "block roadblock" in labels
    assert "Path-1" in labels and "Path-2" in labels
    assert "r1" in labels

    # pucks closer than 0.2 m share one label, so that labels do not overprint
    close = world() |> World.add_puck(:q1, x: 2.5, y: 1.0) |> World.add_puck(:q2, x: 2.6, y: 1.0)

    labels =
      for [l] <-
            Regex.scan(~r/<text class="label"[^>]*>([^<]+)</, Render.svg(close),
              capture: :all_but_first
            ),
          do: l

    assert "2 pucks q1-q2" in labels
    refute "puck q2" in labels

    [puck] = elements(svg, "circle", "puck")
    assert {float(puck["x"]), float(puck["y"])} == {2.0, 2.0}
    [block] = elements(svg, "circle", "puck obstacle")
    assert block["id"] == "roadblock"
    assert svg =~ ~s(data-unit="m")
  end
end
