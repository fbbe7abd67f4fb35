defmodule Mix.Tasks.Tartarus.RoadblockTest do
  use ExUnit.Case, async: false
  import ExUnit.CaptureIO

  @moduletag :tmp_dir

  test "--auto --json: the outputs, and the summary on the last line", %{tmp_dir: dir} do
    out =
      capture_io(fn ->
        Mix.Tasks.Tartarus.Roadblock.run(~w(--auto --seed 1 --json --out #{dir}))
      end)

    s = out |> String.split("\n", trim: true) |> List.last() |> Tartarus.JSON.decode!()

    for key <- ~w(rescued chosen_robot santa_arrived agent_hops seconds),
        do: assert(Map.has_key?(s, key), key)

    assert s["rescued"] and s["chosen_robot"] == "claus" and s["santa_arrived"]

    for f <- ~w(snapshot.png trajectories.svg timeline.csv timeline.svg),
        do: assert(File.exists?(Path.join(dir, f)), f)
  end

  test "--help prints the documentation; bad flags name the flag" do
    assert capture_io(fn -> Mix.Tasks.Tartarus.Roadblock.run(["--help"]) end) =~
             "release_rescue"

    assert_raise Mix.Error, ~r/--mode must be virtual or peer, got: cloud/, fn ->
      Mix.Tasks.Tartarus.Roadblock.run(~w(--mode cloud --auto))
    end

    assert_raise Mix.Error, ~r/--seed/, fn ->
      Mix.Tasks.Tartarus.Roadblock.run(~w(--seed x --auto))
    end
  end
end
