defmodule TartarusImmune.Evolution.SharingTest do
  use ExUnit.Case, async: false

  alias TartarusImmune.Evolution.{Experiment, Sharing}

  doctest Sharing
  doctest Experiment

  test "broadcast: every node shares, the counts come from the platform, the same seed gives the same run" do
    {:ok, a} = Sharing.run(nodes: 12, scheme: :broadcast, seed: 3)
    assert a.converged and a.omega == a.converged_at - a.first_solved_at
    c = a.communications
    assert c.broadcast_messages > 0 and c.broadcast_messages == c.broadcasts_received
    assert c.departures == 0
    assert a.gamma_avg == Float.round((c.broadcast_messages + c.broadcasts_received) / 12, 2)
    {:ok, b} = Sharing.run(nodes: 12, scheme: :broadcast, seed: 3)

    assert Map.take(a, [:omega, :gamma_avg, :solved]) ==
             Map.take(b, [:omega, :gamma_avg, :solved])
  end

  test "iPkts: hand-offs and hello broadcasts are the communications; reproducible" do
    {:ok, a} = Sharing.run(nodes: 12, scheme: :ipkt, ipkts: 2, seed: 3)
    assert a.converged
    c = a.communications
    assert c.departures > 0 and c.departures == c.arrivals
    assert c.broadcast_messages > 0
    {:ok, b} = Sharing.run(nodes: 12, scheme: :ipkt, ipkts: 2, seed: 3)

    assert Map.take(a, [:omega, :gamma_avg, :solved]) ==
             Map.take(b, [:omega, :gamma_avg, :solved])
  end

  test "without sharing nothing is sent; a run that cannot converge says so" do
    {:ok, r} = Sharing.run(nodes: 8, scheme: :none, seed: 1, max_iterations: 2)

    assert r.communications == %{
             broadcast_messages: 0,
             broadcasts_received: 0,
             departures: 0,
             arrivals: 0
           }

    assert r.iterations == 2 and r.converged == false and r.omega == nil
  end

  test "bad options are refused with the key named" do
    assert {:error, message} = Sharing.run(scheme: :shout)
    assert message =~ "for key :scheme"
  end

  test "the experiment writes its files and a summary with gamma_avg and omega per size and scheme" do
    dir = Path.join(System.tmp_dir!(), "evolve-test-#{System.unique_integer([:positive])}")

    try do
      {:ok, %{summary: s, files: files}} =
        Experiment.run(sizes: [10], trials: 1, out: dir, quiet: true, seed: 2)

      assert Map.keys(s.gamma_avg["10"]) |> Enum.sort() == ["b-cast", "iPkt-1", "iPkt-2", "none"]
      assert s.gamma_avg["10"]["none"] == 0.0
      assert s.gamma_avg["10"]["iPkt-1"] < s.gamma_avg["10"]["b-cast"]

      assert Enum.all?(["runs.csv", "gamma_avg.svg", "omega.svg"], fn f ->
               Enum.any?(files, &String.ends_with?(&1, f))
             end)

      assert File.read!(Path.join(dir, "runs.csv")) |> String.split("\n", trim: true) |> length() ==
               5
    after
      File.rm_rf!(dir)
    end
  end
end
