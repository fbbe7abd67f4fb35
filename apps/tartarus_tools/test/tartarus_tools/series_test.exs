defmodule TartarusEmu.SeriesTest do
  use ExUnit.Case, async: true

  alias TartarusTools.Series

  doctest Series

  test "rows line up steps across series, last write wins" do
    s =
      Series.new()
      |> Series.record(:a, 3, 30)
      |> Series.record(:a, 1, 10)
      |> Series.record("b", 2, 2.5)
      |> Series.record(:a, 3, 31)

    assert Series.names(s) == [:a, "b"]
    assert Series.header(s) == ["step", "a", "b"]
    assert Series.to_rows(s) == [[1, 10, nil], [2, nil, 2.5], [3, 31, nil]]
    assert Series.points(s, :missing) == []
  end

  test "feeds CSV and charts" do
    s = Series.new() |> Series.record(:pop, 0, 1) |> Series.record(:pop, 1, :na)

    assert TartarusTools.Report.to_csv(Series.header(s), Series.to_rows(s)) ==
             "step,pop\n0,1\n1,na\n"

    assert Series.to_chart(s) == [%{name: "pop", points: [{0, 1}]}]
    assert TartarusTools.SVG.line_chart(Series.to_chart(s)) =~ "pop"
  end
end
