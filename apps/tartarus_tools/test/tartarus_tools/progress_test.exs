defmodule TartarusEmu.ProgressTest do
  use ExUnit.Case, async: true

  import ExUnit.CaptureIO

  alias TartarusTools.Progress

  doctest Progress

  test "quiet and non-terminal runs print nothing" do
    output =
      capture_io(:stderr, fn ->
        p = Progress.new(10, quiet: true)
        p |> Progress.advance(10) |> Progress.finish()
        # Under `mix test` standard error is captured, hence not a terminal.
        Progress.new(10) |> Progress.advance() |> Progress.finish()
      end)

    assert output == ""
  end

  test "enabled runs redraw in place and end with a newline" do
    output =
      capture_io(:stderr, fn ->
        p = Progress.new(4, label: "demo", enabled: true, interval_ms: 0)
        p = Enum.reduce(1..4, p, fn _, p -> Progress.advance(p) end)
        Progress.finish(p)
      end)

    assert output =~ "\rdemo  25.0%  1/4"
    assert output =~ "\rdemo  100.0%  4/4"
    assert String.ends_with?(output, "\n")
    assert output |> String.split("\n") |> length() == 2
  end

  test "render/2 formats long ETAs and zero totals" do
    p = %Progress{total: 10_000, done: 1, started_ms: 0}
    assert Progress.render(p, 1000) == "0.0%  1/10000  1.0/s  elapsed 0:01  ETA 2:46:39"
    assert Progress.render(%Progress{total: 0, done: 0, started_ms: 0}, 5) =~ "100.0%  0/0"
  end
end
