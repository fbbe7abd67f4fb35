defmodule TartarusEmu.SweepProgressTest do
  # `TartarusTools.Progress.force/1` is the VM's: this runs alone.
  use ExUnit.Case, async: false

  import ExUnit.CaptureIO

  alias TartarusEmu.{Sweep, Walk}

  setup do
    on_exit(fn -> TartarusTools.Progress.force(false) end)
  end

  defp spec do
    %{
      name: "walks",
      arms: [{"many", [agents: 4]}, {"one", [agents: 1]}],
      seeds: [1],
      scenario: Walk,
      base: [topology: "ring", hosts: 8, steps: 100, until_covered: true],
      metrics: [steps: :steps]
    }
  end

  test "a run that asked for progress gets a line per run, quiet and not on a terminal" do
    silent = capture_io(:stderr, fn -> {:ok, _} = Sweep.run(spec(), out: false, quiet: true) end)
    assert silent == ""

    TartarusTools.Progress.force(true)
    printed = capture_io(:stderr, fn -> {:ok, _} = Sweep.run(spec(), out: false, quiet: true) end)
    lines = String.split(printed, "\n", trim: true)
    assert length(lines) == 2

    assert Enum.all?(
             lines,
             &(&1 =~ ~r/^walks \[\d\/2\] (many|one) seed 1 \(\d+\.\d s\)  elapsed/)
           )
  end
end
