defmodule TartarusArena.ExperimentTest do
  use ExUnit.Case, async: false

  alias TartarusArena.Experiment

  @tag :tmp_dir
  test "the arena run writes its outputs and a summary with the documented keys", %{tmp_dir: dir} do
    {:ok, %{summary: s, out: ^dir}} = Experiment.run(seed: 2, laps: 1, bench_seconds: 5, out: dir)

    for f <-
          ~w(lap_times.csv subpaths.csv snapshot.svg bench_snapshot.svg camera.png runs.csv summary.json summary.md) ++
            for(i <- 1..8, do: "trajectories_A#{i}.svg"),
        do: assert(File.exists?(Path.join(dir, f)), f)

    assert Map.keys(s.lap_times) == ~w(A1 A2 A3 A4 A5 A6 A7 A8)
    assert Enum.all?(s.lap_times, fn {_, %{path1: p1}} -> length(p1) == 1 end)
    assert Map.keys(s.exhaustive_best) == [:sp_a, :sp_b, :sp_c, :sp_d]
    assert s.sim_speed_x > 0 and s.sim_speed_cpu_x > 0 and s.sim_speed_robots == 3
    # 8 PFAs over the 4 + 5 sub-paths
    assert length(File.read!(Path.join(dir, "subpaths.csv")) |> String.split("\n", trim: true)) ==
             1 + 8 * 9

    {:ok, json} = Tartarus.JSON.decode(File.read!(Path.join(dir, "summary.json")))
    assert json["exhaustive_best"]["sp_a"] == s.exhaustive_best.sp_a

    # a PFA is an arm of the sweep: a row of runs.csv each, in the PFAs' order
    [header | rows] = File.read!(Path.join(dir, "runs.csv")) |> String.split("\n", trim: true)
    assert header == "arm,seed,lap_path1,lap_path2,lost_path1,lost_path2,subpath_cost"
    assert Enum.map(rows, &hd(String.split(&1, ","))) == Map.keys(s.lap_times)
    assert s.sweep.aggregates["A4"].lost_path2.n == 1
    assert s.sweep.aggregates["A4"].lost_path2.median == s.lost["A4"].path2

    # summary.md: the key table, then the arena's own tables
    md = File.read!(Path.join(dir, "summary.md"))
    assert md =~ ~r/^# Arena run \(seed 2\)\n/
    assert md =~ Experiment.markdown(s) and md =~ "## Provenance"
  end

  test "bad options are refused with a message" do
    assert {:error, msg} = Experiment.run(laps: 0)
    assert msg =~ "for key :laps: expected a positive integer, got: 0"
  end

  test "mix tartarus.arena --help prints the task's documentation" do
    Mix.shell(Mix.Shell.Process)
    on_exit(fn -> Mix.shell(Mix.Shell.IO) end)
    Mix.Tasks.Tartarus.Arena.run(["--help"])
    assert_received {:mix_shell, :info, [text]}
    assert text =~ "mix tartarus.arena" and text =~ "sim_speed_x"
  end
end
