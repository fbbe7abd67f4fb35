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

defmodule TartarusTools.ProgressForcedTest do
  # `force/1` is the VM's: these run alone (the async tests above expect silence).
  use ExUnit.Case, async: false

  import ExUnit.CaptureIO

  alias TartarusTools.Progress

  setup do
    on_exit(fn -> Progress.force(false) end)
  end

  test "--progress reaches every task: it is taken out of the arguments and forces the lines" do
    refute Progress.forced?()

    # The task's own parser never sees the flag: the error names the other one.
    error =
      assert_raise Mix.Error, fn ->
        Mix.Tasks.Tartarus.Warehouse.run(["--progress", "--bogus"])
      end

    assert error.message =~ "--bogus"
    refute error.message =~ "--progress"
    assert Progress.forced?()
  end

  test "forced, a quiet run on a device that is not a terminal prints plain lines, throttled" do
    Progress.force(true)

    output =
      capture_io(:stderr, fn ->
        p = Progress.new(3, label: "long", quiet: true)
        # The first advance prints, the next two fall within 10 s of it; finish prints.
        p |> Progress.advance() |> Progress.advance() |> Progress.advance(0) |> Progress.finish()
      end)

    lines = String.split(output, "\n", trim: true)
    assert [first, last] = lines
    assert first =~ ~r/^long  33\.3%  1\/3 /
    assert last =~ ~r/^long  66\.7%  2\/3 /
    refute output =~ "\r"
    refute output =~ "\e["
  end

  test "nothing is printed while the VM runs in virtual time" do
    Progress.force(true)

    output =
      capture_io(:stderr, fn ->
        Tartarus.Clock.Virtual.run([seed: 1], fn ->
          Progress.new(2, label: "vt") |> Progress.advance(2) |> Progress.finish()
        end)

        Progress.new(1, label: "after") |> Progress.finish()
      end)

    refute output =~ "vt"
    assert output =~ "after"
  end
end
