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

    test "the footnote names what is drawn: dots for small groups, open circles for outliers" do
      note = fn svg ->
        [_, text] = Regex.run(~r/<text class="note"[^>]*>([^<]*)</, svg)
        text
      end

      # Five samples, none beyond the whiskers: every sample a dot, no outlier named.
      small = SVG.box_plot([{"a", [3, 4, 5, 6, 7]}])
      refute small =~ ~s(class="outlier")
      assert length(Regex.scan(~r/class="sample"/, small)) == 5
      assert note.(small) =~ "dots beside a box: each of its samples"
      refute note.(small) =~ ~r/outlier|circles/

      # One sample far out: an open circle, and the note says what it is.
      far = SVG.box_plot([{"a", [3, 4, 5, 6, 7, 100]}])
      assert length(Regex.scan(~r/class="outlier"/, far)) == 1
      assert note.(far) =~ "open circles: samples beyond the whiskers"

      # 30 samples: no dots, and the note does not promise them.
      many = SVG.box_plot([{"a", Enum.to_list(1..30)}])
      refute many =~ ~s(class="sample")
      refute note.(many) =~ "dots"
      mixed = SVG.box_plot([{"a", Enum.to_list(1..30)}, {"b", [1, 2]}])
      assert note.(mixed) =~ "dots beside a box of at most 20 samples: each of them"
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

  # Reading numbers back from a chart: the y-axis tick labels (text-anchor "end" at the
  # left margin) give the linear map from data to pixels; the x-axis ones (y below the plot)
  # the x map.
  defp y_ticks(svg) do
    for [_, y, v] <- Regex.scan(~r/<text x="64(?:\.00)?" y="([\d.]+)" text-anchor="end">([^<]+)<\/text>/, svg),
        do: {String.to_float(y) - 4, v}
  end

  defp x_ticks(svg) do
    for [_, x, v] <-
          Regex.scan(~r/<text x="([\d.]+)" y="376(?:\.00)?" text-anchor="middle">([^<]+)<\/text>/, svg),
        do: {String.to_float(x), v}
  end

  defp to_number(v) do
    case Float.parse(v) do
      {f, ""} -> f
      _ -> raise "not a number: #{v}"
    end
  end

  # Pixel -> data, from two ticks.
  defp inverse([{p0, v0}, {p1, v1} | _]) do
    {v0, v1} = {to_number(v0), to_number(v1)}
    fn p -> v0 + (p - p0) / (p1 - p0) * (v1 - v0) end
  end

  describe "numbers read back from the drawing" do
    test "a box plot's median line sits at the conventional median of its samples" do
      groups = [{"even", [13, 11]}, {"odd", [1, 2, 3, 4, 50]}, {"many", Enum.to_list(1..30)}]
      svg = SVG.box_plot(groups, title: "steps", y_label: "steps")
      to_value = inverse(y_ticks(svg))

      medians =
        for [_, v, y] <-
              Regex.scan(~r/<g class="median" data-value="([^"]+)"><line x1="[\d.]+" y1="([\d.]+)"/, svg),
            do: {to_number(v), to_value.(String.to_float(y))}

      assert length(medians) == 3

      for {{_, samples}, {v, drawn}} <- Enum.zip(groups, medians) do
        assert v == TartarusTools.Stats.median_mid(samples)
        assert_in_delta drawn, TartarusTools.Stats.median_mid(samples), 0.05
      end

      # [11, 13]: the median line is at 12 (not at the nearest-rank 11), and the footnote says so.
      assert elem(hd(medians), 0) == 12
      assert_in_delta elem(hd(medians), 1), 12, 0.05
      assert svg =~ "of an even n, the mean of the two middle samples"
      # Small groups show their samples, at their values; the group of 30 does not.
      dots = Regex.scan(~r/<circle class="sample" cx="[\d.]+" cy="([\d.]+)"[^>]*data-value="([^"]+)"/, svg)
      assert Enum.map(dots, fn [_, _, v] -> to_number(v) end) == [11, 13, 1, 2, 3, 4, 50]

      for [_, cy, v] <- dots,
          do: assert_in_delta(to_value.(String.to_float(cy)), to_number(v), 0.05)
    end

    test "integer axes get integer ticks; fractional data keeps fractional ticks" do
      svg =
        SVG.line_chart([%{name: "speed-up", points: [{1, 1.0}, {2, 1.8}, {3, 2.4}, {4, 2.9}]}],
          title: "robots"
        )

      xs = Enum.map(x_ticks(svg), &elem(&1, 1))
      assert xs == ["1", "2", "3", "4"]
      refute "1.5" in xs
      assert Enum.any?(y_ticks(svg), fn {_, v} -> v =~ "." end)

      laps = SVG.line_chart([%{name: "lap", points: [{1, 3}, {2, 4}, {3, 5}]}])
      assert Enum.all?(x_ticks(laps) ++ y_ticks(laps), fn {_, v} -> not (v =~ ".") end)

      forced = SVG.line_chart([%{name: "a", points: [{0.0, 0.0}, {3.0, 1.0}]}], x_integer: true)
      assert Enum.map(x_ticks(forced), &elem(&1, 1)) == ["0", "1", "2", "3"]

      boxes = SVG.box_plot([{"a", [1, 2, 3]}])
      assert Enum.map(y_ticks(boxes), &elem(&1, 1)) == ["1", "2", "3"]
    end

    test "means over trials carry their 95 % intervals, drawn at their values" do
      trials = [{1, [10, 12, 14]}, {2, [8, 9, 10, 11]}, {3, [7]}]
      series = SVG.mean_series("path 1", trials)
      svg = SVG.line_chart([series], title: "laps", note: SVG.ci_note(Enum.map(trials, &length(elem(&1, 1))), "trials"))
      to_value = inverse(y_ticks(svg))

      drawn =
        Regex.scan(
          ~r/<g class="interval" data-x="([^"]+)" data-lo="([^"]+)" data-hi="([^"]+)">.*?<\/title>\n<line x1="[\d.]+" y1="([\d.]+)" x2="[\d.]+" y2="([\d.]+)"/s,
          svg
        )

      # The single-trial lap has a point and no bar.
      assert length(drawn) == 2

      for [_, x, lo, hi, ylo, yhi] <- drawn do
        {_, samples} = List.keyfind(trials, String.to_integer(x), 0)
        ci = TartarusTools.Stats.mean_ci(samples)
        assert_in_delta to_number(lo), ci.lo, 1.0e-3
        assert_in_delta to_number(hi), ci.hi, 1.0e-3
        assert_in_delta to_value.(String.to_float(ylo)), ci.lo, 0.05
        assert_in_delta to_value.(String.to_float(yhi)), ci.hi, 0.05
      end

      assert series.points == [{1, 12.0}, {2, 9.5}, {3, 7.0}]
      assert svg =~ "points: mean over 1-4 trials; error bars: 95 % confidence interval"
    end

    test "reference lines and thesis points are drawn at their values and named in the legend" do
      svg =
        SVG.line_chart([%{name: "ours", points: [{1, 1.0}, {2, 1.7}, {3, 2.0}, {4, 2.3}]}],
          title: "speed-up",
          subtitle: "jobs 16, seed 1",
          references: [
            %{name: "ideal (k robots: k)", points: [{1, 1}, {4, 4}]},
            %{name: "thesis (§4.7.4)", points: [{2, 1.75}, {3, 1.84}, {4, 2.21}], style: :points}
          ]
        )

      t = texts(svg)
      assert "ideal (k robots: k)" in t and "thesis (§4.7.4)" in t and "jobs 16, seed 1" in t
      to_value = inverse(y_ticks(svg))
      to_x = inverse(x_ticks(svg))

      crosses =
        Regex.scan(
          ~r/<g class="reference" data-x="([^"]+)" data-y="([^"]+)">.*?<\/title>\n<line x1="([\d.]+)" y1="([\d.]+)"/s,
          svg
        )

      assert Enum.map(crosses, fn [_, x, y | _] -> {to_number(x), to_number(y)} end) ==
               [{2, 1.75}, {3, 1.84}, {4, 2.21}]

      for [_, x, y, px, py] <- crosses do
        # The cross is centred 5 px right and below its first stroke's start.
        assert_in_delta to_x.(String.to_float(px) + 5), to_number(x), 0.01
        assert_in_delta to_value.(String.to_float(py) + 5), to_number(y), 0.01
      end

      assert svg =~ ~s(stroke-dasharray="6 4")
    end

    test "a bar's error bar spans lo..hi" do
      svg = SVG.bar_chart([%{label: "8: shared", value: 5.0, lo: 4.0, hi: 6.5}], note: "95 % CI")
      to_value = inverse(y_ticks(svg))

      [[_, lo, hi, y1, y2]] =
        Regex.scan(
          ~r/<g class="interval" data-lo="([^"]+)" data-hi="([^"]+)">.*?<\/title>\n<line x1="[\d.]+" y1="([\d.]+)" x2="[\d.]+" y2="([\d.]+)"/s,
          svg
        )

      assert {to_number(lo), to_number(hi)} == {4.0, 6.5}
      assert_in_delta to_value.(String.to_float(y1)), 4.0, 0.02
      assert_in_delta to_value.(String.to_float(y2)), 6.5, 0.02
      assert "95 % CI" in texts(svg)
      assert_raise ArgumentError, fn -> SVG.bar_chart([%{label: "x", value: 1, lo: 2, hi: 1}]) end
    end
  end
end
