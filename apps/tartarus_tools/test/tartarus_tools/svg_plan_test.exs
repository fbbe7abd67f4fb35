defmodule TartarusTools.SVGPlanTest do
  use ExUnit.Case, async: true

  alias TartarusTools.SVG

  test "one scale for both axes; the scale bar is a nice length that measures it" do
    svg =
      SVG.plan(
        [
          %{shape: :circle, x: 0, y: 0, r_px: 4, class: "node", data: %{id: "a"}},
          %{shape: :circle, x: 3, y: 2, r_px: 4, class: "node", data: %{id: "b"}}
        ],
        bounds: {0, 0, 3, 2},
        unit: "m"
      )

    [k] = Regex.run(~r/data-px-per-unit="([^"]+)"/, svg, capture: :all_but_first)
    k = String.to_float(k)
    [[ax, ay], [bx, by]] = Regex.scan(~r/<circle cx="([\d.]+)" cy="([\d.]+)"/, svg, capture: :all_but_first)
    assert_in_delta String.to_float(bx) - String.to_float(ax), 3 * k, 0.02
    # y grows upwards: b (y = 2) is drawn 2 m above a
    assert_in_delta String.to_float(ay) - String.to_float(by), 2 * k, 0.02
    [len, px] = Regex.run(~r/class="scale-bar" data-length="([^"]+)" data-unit="m" data-px="([^"]+)"/, svg, capture: :all_but_first)
    assert len in ~w(0.5 0.2 0.1 1 2 5)
    assert_in_delta String.to_float(px), elem(Float.parse(len), 0) * k, 0.02
  end

  test "start and end markers, labels and tooltips; no scale bar without a unit" do
    svg =
      SVG.plan([
        %{shape: :line, points: [{0, 0}, {1, 0}], arrow: true, width_px: 2, class: "hop"},
        %{shape: :marker, kind: :start, x: 0, y: 0, title: "start"},
        %{shape: :marker, kind: :end, x: 1, y: 0, label: "here & now"}
      ])

    assert svg =~ ~s(<circle class="start")
    assert svg =~ ~s(<rect class="end")
    assert svg =~ "here &amp; now"
    assert svg =~ "<polygon"
    refute svg =~ "scale-bar"
  end

  test "a malformed shape is an ArgumentError naming the plan and the shape" do
    assert_raise ArgumentError, ~r/SVG.plan\/2: expected shapes .* got: %\{shape: :circle/, fn ->
      SVG.plan([%{shape: :circle, x: 0, y: 0}])
    end

    assert_raise ArgumentError, ~r/SVG.plan\/2/, fn -> SVG.plan([%{shape: :line, points: [{0, 0}, {:a, 1}]}]) end
  end
end
