defmodule TartarusImmune.Evolution.DensityTest do
  use ExUnit.Case, async: false

  alias TartarusImmune.Evolution.{Experiment, Sharing}
  alias TartarusImmune.Evolution.Experiment.Density

  doctest Density

  test "more link stubs per node: a denser potential graph and more live neighbours; 5 is Fig. 7.6's graph" do
    assert Sharing.topology(30, 2) == Sharing.topology(30, 2, 5)
    {:ok, sparse} = Sharing.run(nodes: 16, degree: 1, scheme: :broadcast, seed: 5)
    {:ok, dense} = Sharing.run(nodes: 16, degree: 8, scheme: :broadcast, seed: 5)
    assert sparse.potential_degree <= 1.0
    assert dense.potential_degree > 4 * sparse.potential_degree
    # every link starts live and half are down in the long run
    assert sparse.mean_degree > 0 and sparse.mean_degree <= sparse.potential_degree
    assert dense.mean_degree > 2 * sparse.mean_degree
    # a broadcast is a message to every live neighbour: more of them per iteration
    assert dense.communications.broadcast_messages / dense.iterations >
             sparse.communications.broadcast_messages / sparse.iterations
  end

  test "the density experiment at a small size: ratios, tests and a verdict per size, files written" do
    dir = Path.join(System.tmp_dir!(), "density-test-#{System.unique_integer([:positive])}")

    try do
      {:ok, %{summary: s, files: files}} =
        Experiment.run(
          experiment: :density,
          sizes: [10],
          degrees: [1, 4],
          trials: 2,
          seed: 3,
          out: dir,
          quiet: true
        )

      size = s.density["10"]
      assert size.judged == "iPkt-1"
      assert Map.keys(size.by_degree) |> Enum.sort() == ["1", "4"]

      for {_, b} <- size.by_degree do
        assert Map.keys(b.gamma_avg) |> Enum.sort() == ["b-cast", "iPkt-1", "iPkt-2"]

        assert_in_delta b.ratio["iPkt-1"], b.gamma_avg["iPkt-1"] / b.gamma_avg["b-cast"], 0.01

        assert b.p_bcast_fewer >= 0 and b.p_ipkt_fewer <= 1
      end

      assert size.by_degree["4"].live_degree > size.by_degree["1"].live_degree

      assert size.claim_reproduced ==
               (size.by_degree["1"].p_bcast_fewer < 0.05 and
                  size.by_degree["4"].p_ipkt_fewer < 0.05)

      assert s.claim_reproduced == %{"10" => size.claim_reproduced}

      assert Enum.all?(["density_ratio.svg", "density_gamma.svg", "runs.csv"], fn f ->
               Enum.any?(files, &String.ends_with?(&1, f))
             end)

      # a row per run: 2 degrees x 3 schemes x 2 trials
      rows = File.read!(Path.join(dir, "runs.csv")) |> String.split("\n", trim: true)
      assert length(rows) == 1 + 2 * 3 * 2
      assert hd(rows) =~ "nodes,degree,scheme,trial,potential_degree,mean_degree,gamma_avg"
    after
      File.rm_rf!(dir)
    end
  end

  test "mix tartarus.evolve --experiment density: --help, a bad --degrees, --json with provenance" do
    Mix.shell(Mix.Shell.Process)
    on_exit(fn -> Mix.shell(Mix.Shell.IO) end)
    Mix.Tasks.Tartarus.Evolve.run(["--help"])
    assert_received {:mix_shell, :info, [text]}
    assert text =~ "--degrees" and text =~ "claim_reproduced"

    assert_raise Mix.Error, ~r/invalid value for --degrees/, fn ->
      Mix.Tasks.Tartarus.Evolve.run(~w(--experiment density --degrees 0,x))
    end

    dir = Path.join(System.tmp_dir!(), "density-task-#{System.unique_integer([:positive])}")

    try do
      Mix.Tasks.Tartarus.Evolve.run(
        ~w(--experiment density --sizes 8 --degrees 2 --seeds 1 --seed 4 --json --out) ++ [dir]
      )

      assert_received {:mix_shell, :info, [json]}
      {:ok, s} = Tartarus.JSON.decode(json)
      assert s["experiment"] == "density" and s["degrees"] == [2]
      assert is_boolean(s["claim_reproduced"]["8"])
      assert s["provenance"]["argv"] != nil
    after
      File.rm_rf!(dir)
    end
  end
end
