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

      assert File.read!(Path.join(dir, "gamma_avg.svg")) =~ "one trial per bar: no interval"
    after
      File.rm_rf!(dir)
    end
  end

  test "gamma_avg.svg over several trials: each bar is the mean, its error bar the 95 % interval" do
    dir = Path.join(System.tmp_dir!(), "evolve-test-#{System.unique_integer([:positive])}")

    try do
      {:ok, %{summary: s}} =
        Experiment.run(sizes: [10], trials: 3, out: dir, quiet: true, seed: 2)

      svg = File.read!(Path.join(dir, "gamma_avg.svg"))

      [header | rows] =
        dir
        |> Path.join("runs.csv")
        |> File.read!()
        |> String.split("\n", trim: true)
        |> Enum.map(&String.split(&1, ","))

      runs = Enum.map(rows, &Map.new(Enum.zip(header, &1)))

      bars =
        Regex.scan(~r/<rect [^>]*><title>10: ([^:]+): ([^<]+)<\/title>/, svg,
          capture: :all_but_first
        )

      assert Enum.map(bars, &hd/1) == ["none", "b-cast", "iPkt-1", "iPkt-2"]

      for [label, v] <- bars do
        xs =
          for r <- runs,
              r["nodes"] == "10" and r["scheme"] == label,
              do: elem(Float.parse(r["gamma_avg"]), 0)

        assert length(xs) == 3
        assert_in_delta elem(Float.parse(v), 0), s.gamma_avg["10"][label], 1.0e-9
        ci = TartarusTools.Stats.mean_ci(xs)

        assert [[lo, hi]] =
                 Regex.scan(
                   ~r/<g class="interval" data-lo="([^"]+)" data-hi="([^"]+)"><title>10: #{Regex.escape(label)}:/,
                   svg,
                   capture: :all_but_first
                 )

        assert_in_delta elem(Float.parse(lo), 0), ci.lo, 1.0e-3
        assert_in_delta elem(Float.parse(hi), 0), ci.hi, 1.0e-3
      end

      assert svg =~ "bars: mean over 3 trials; error bars: 95 % confidence interval"
      assert svg =~ "seeds 2-4"
    after
      File.rm_rf!(dir)
    end
  end
end
