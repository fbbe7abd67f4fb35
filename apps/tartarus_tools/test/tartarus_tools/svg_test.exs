defmodule TartarusEmu.SVGTest do
  use ExUnit.Case, async: true

  alias TartarusTools.SVG

  doctest SVG

  # Parses the document with OTP's xmerl (raises on invalid XML) and returns all text nodes.
  # xmerl gets the raw UTF-8 bytes and decodes them as the XML declaration says.
  defp texts(svg) do
    {doc, []} = :xmerl_scan.string(:binary.bin_to_list(svg), quiet: true)

    doc
    |> collect()
    |> Enum.map(&(&1 |> List.to_string() |> String.trim()))
    |> Enum.reject(&(&1 == ""))
  end

  defp collect({:xmlElement, _name, _, _, _, _, _, _attrs, content, _, _, _}),
    do: Enum.flat_map(content, &collect/1)

  defp collect({:xmlText, _, _, _, value, _}), do: [value]
  defp collect(_), do: []

  defp root_name(svg) do
    {doc, []} = :xmerl_scan.string(:binary.bin_to_list(svg), quiet: true)
    elem(doc, 1)
  end

  describe "line_chart/2" do
    test "valid XML with title, labels, units and series names in the legend" do
      svg =
        SVG.line_chart(
          [
            %{name: "clones", points: for(x <- 0..100, do: {x, x * x})},
            %{name: :apoptosis, points: [{0, 5.5}, {50, 2.25}]}
          ],
          title: "Population <iPkts> & co",
          x_label: "time",
          x_unit: "steps",
          y_label: "count"
        )

      assert root_name(svg) == :svg
      t = texts(svg)
      assert "Population <iPkts> & co" in t
      assert "clones" in t
      assert "apoptosis" in t
      assert "time (steps)" in t
      assert "count" in t
      assert svg =~ "<polyline"
    end

    test "edge cases do not crash" do
      for series <- [
            [],
            [%{name: "empty", points: []}],
            [%{name: "one", points: [{3, 3}]}],
            [%{name: "flat", points: [{0, 7}, {1, 7}, {2, 7}]}],
            [%{name: "zero", points: [{0, 0}, {0, 0}]}],
            [%{name: "tiny", points: [{0, 1.0e-9}, {1, 2.0e-9}]}],
            [%{name: "huge", points: [{0, -1.0e12}, {1, 3.0e12}]}],
            [%{name: {:tuple, "name"}, points: [{1, 2}]}]
          ] do
        svg = SVG.line_chart(series)
        assert root_name(svg) == :svg
      end

      assert "no data" in texts(SVG.line_chart([]))
    end

    test "unicode and control characters stay valid XML" do
      svg = SVG.line_chart([%{name: "é 😀 \u0001 'q'", points: [{0, 1}]}], title: "Ωmega")
      t = texts(svg)
      assert "Ωmega" in t
      assert "é 😀  'q'" in t
      assert svg =~ "é 😀  &apos;q&apos;"
    end

    test "malformed points are refused clearly" do
      assert_raise ArgumentError,
                   ~r/expected points \{x, y\} of numbers in series "s", got: \{1, :a\}/,
                   fn ->
                     SVG.line_chart([%{name: "s", points: [{1, :a}]}])
                   end

      assert_raise ArgumentError, ~r/expected series %\{name: term, points/, fn ->
        SVG.line_chart([1])
      end
    end
  end

  describe "bar_chart/2" do
    test "labels and values appear, negative values work" do
      svg =
        SVG.bar_chart([%{label: "ours", value: 3.5}, {"thesis", -2}, {:other, 0}],
          title: "Bars",
          y_label: "hops"
        )

      t = texts(svg)
      assert Enum.all?(["Bars", "ours", "thesis", "other", "3.5", "-2", "hops"], &(&1 in t))
    end

    test "edge cases" do
      assert "no data" in texts(SVG.bar_chart([]))
      assert root_name(SVG.bar_chart(for i <- 1..30, do: {"bar #{i}", i})) == :svg
      assert root_name(SVG.bar_chart([{"z", 0}])) == :svg

      assert_raise ArgumentError, ~r/expected bars/, fn -> SVG.bar_chart([{"a", "1"}]) end
    end
  end

  describe "box_plot/2" do
    test "renders groups, counts and outliers" do
      svg =
        SVG.box_plot(
          [{"line", [1, 2, 3, 4, 5, 40]}, %{name: "ring", samples: [2, 2, 2]}, {"none", []}],
          title: "Hops per query",
          y_label: "hops"
        )

      t = texts(svg)

      assert Enum.all?(
               ["Hops per query", "line", "ring", "none", "n=6", "n=3", "n=0", "hops"],
               &(&1 in t)
             )

      assert svg =~ "<circle"
    end

    test "edge cases" do
      assert "no data" in texts(SVG.box_plot([]))
      assert "no data" in texts(SVG.box_plot([{"a", []}]))
      assert_raise ArgumentError, ~r/expected groups/, fn -> SVG.box_plot([:bad]) end
    end
  end

  describe "gantt/2" do
    test "rows, span labels, groups in the legend" do
      rows = [
        %{label: "robot-1", spans: [%{start: 0, stop: 10, label: "task A", group: "move"}]},
        %{
          label: "robot-2",
          spans: [
            %{start: 2, stop: 3, label: "a very long label that does not fit", group: "lift"},
            %{start: 5, stop: 9}
          ]
        }
      ]

      svg = SVG.gantt(rows, title: "Schedule", x_label: "time", x_unit: "s")
      t = texts(svg)

      assert Enum.all?(
               ["Schedule", "robot-1", "robot-2", "task A", "move", "lift", "time (s)"],
               &(&1 in t)
             )

      # The long label does not fit its bar: tooltip only.
      assert Enum.any?(t, &(&1 =~ "a very long label that does not fit (lift) 2–3"))
    end

    test "edge cases and errors" do
      assert "no data" in texts(SVG.gantt([]))
      assert root_name(SVG.gantt([%{label: "r", spans: []}])) == :svg
      assert root_name(SVG.gantt([%{label: "r", spans: [%{start: 4, stop: 4}]}])) == :svg

      assert_raise ArgumentError, ~r/start <= stop in row "r", got: %\{start: 5, stop: 1\}/, fn ->
        SVG.gantt([%{label: "r", spans: [%{start: 5, stop: 1}]}])
      end
    end
  end

  test "nice_ticks/3 covers the range with round steps" do
    for {lo, hi} <- [{0, 1}, {-3, 7}, {0.001, 0.0042}, {1, 1_000_000}, {-5, -5}, {0, 0}, {3, 2}] do
      ticks = SVG.nice_ticks(lo, hi)
      assert hd(ticks) <= min(lo, hi) and List.last(ticks) >= max(lo, hi)
      assert length(ticks) in 2..12
    end
  end

  test "write!/2 creates directories" do
    dir = Path.join(System.tmp_dir!(), "svg_test_#{System.unique_integer([:positive])}")
    path = Path.join([dir, "plots", "a.svg"])

    try do
      assert SVG.write!(path, SVG.bar_chart([{"a", 1}])) == path
      assert root_name(File.read!(path)) == :svg
    after
      File.rm_rf!(dir)
    end
  end
end
