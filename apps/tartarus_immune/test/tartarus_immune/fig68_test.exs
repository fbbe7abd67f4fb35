defmodule TartarusImmune.Fig68Test do
  use ExUnit.Case, async: false

  alias TartarusImmune.{Experiment, Select}
  alias TartarusImmune.Select.Fig68
  doctest TartarusImmune.Select.Fig68
  doctest TartarusImmune.Sorting.Comparisons

  describe "the guard against an uninformative configuration" do
    test "a few lucky runs do not make the first barrage possible (5 % of 80 runs = 4)" do
      # 3 runs converge in window 1, the rest of both arms in window 2: window 2 is the
      # first where convergence is possible and every run is there or earlier: fired
      signals = [5, 5, 5] ++ List.duplicate(12, 37)
      without = List.duplicate(11, 40)
      g = Fig68.guard(signals, without, 10)
      assert {g.first_barrage, g.rounds, g.at_first, g.fired} == {2, {11, 20}, {40, 40}, true}
      # a fourth run in window 1 makes it the first barrage: then few runs are at it
      g = Fig68.guard([5 | tl(signals)] |> List.replace_at(3, 6), without, 10)
      assert {g.first_barrage, g.at_first, g.fired} == {1, {4, 0}, false}
    end

    test "fires only when half of the runs of both arms are at the first barrage" do
      half = List.duplicate(12, 20) ++ List.duplicate(35, 20)
      less = List.duplicate(12, 19) ++ List.duplicate(35, 21)
      assert Fig68.guard(half, half, 10).fired
      refute Fig68.guard(half, less, 10).fired
      refute Fig68.guard(less, half, 10).fired
      # runs that did not converge count at the step limit
      refute Fig68.guard(half, List.duplicate(12, 4) ++ List.duplicate(600, 36), 10).fired
    end
  end

  describe "the verdict" do
    @d %{median: 12, iqr: 2, mean: 13.0}
    @nd %{median: 15, iqr: 6, mean: 17.0}
    @ns %{median: 40, iqr: 20, mean: 45.0}

    test "the guard makes any outcome uninformative" do
      v =
        Fig68.verdict(
          danger: @d,
          no_danger: @nd,
          no_sharing: @ns,
          p_value: 0.001,
          guard: %{fired: true}
        )

      assert v.outcome == "uninformative"
      assert Enum.all?(Map.values(v.criteria))
    end

    test "each criterion can fail it" do
      base = [danger: @d, no_danger: @nd, no_sharing: @ns, p_value: 0.01, guard: %{fired: false}]
      assert Fig68.verdict(base).outcome == "pass"

      for {change, key} <- [
            {[p_value: 0.05], :p_below_0_05},
            {[danger: %{@d | median: 15}], :median_lower},
            {[danger: %{@d | mean: 17.0}], :mean_lower},
            {[no_sharing: %{@ns | median: 14}], :no_sharing_slowest},
            {[no_sharing: %{@ns | mean: 16.0}], :no_sharing_slowest}
          ] do
        v = Fig68.verdict(Keyword.merge(base, change))
        assert v.outcome == "fail", inspect(change)
        refute v.criteria[key], inspect(change)
      end
    end
  end

  test "seed_hosts: the initial iPkts on k random hosts, the others empty" do
    opts = %{set: :p4, nodes: 6, seed_hosts: 2, train: 20, test: 5, quiet: true}

    queues = fn seed ->
      {:ok, st} =
        Experiment.setup(
          Map.merge(opts, %{seed: seed, rng: :rand.seed_s(:exsss, seed), steps: 1})
        )

      try do
        for h <- st.hosts do
          {:ok, q} = Tartarus.request({"immune", h}, :queue)
          length(q)
        end
      after
        Experiment.teardown(st)
      end
    end

    a = queues.(1)
    assert Enum.sort(a) == [0, 0, 0, 0, 4, 4]
    assert queues.(1) == a
    # another seed, other hosts (for these two seeds)
    refute queues.(2) == a
  end

  test "fig6_8 reports the pre-registered keys and names its deviations" do
    {:ok, r} =
      Select.run(
        experiment: :fig6_8,
        nodes: 6,
        steps: 30,
        hold: 5,
        seeds: 2,
        quiet: true,
        out: false
      )

    p = r.summary.preregistered
    assert p.date == "2026-11-27"
    assert p.deviations == [:nodes, :steps, :hold, :seeds]
    refute p.as_preregistered
    assert p.verdict in ~w(pass fail uninformative)
    assert Map.keys(p.per_arm) |> Enum.sort() == ~w(danger no_danger no_sharing)
    assert %{median: _, iqr: _, mean: _, sd: _, n: 2} = p.per_arm["danger"].rounds
    assert %{median: _, iqr: _, mean: _, sd: _, n: 2} = p.per_arm["no_sharing"].events
    assert is_float(p.p_signals_less_rounds) and is_float(p.p_signals_less_events)
    assert is_boolean(p.guard.fired)
    assert r.summary.sweep.arms == ["danger p4", "no_danger p4", "no_sharing p4"]
  end

  test "--cost comparisons is labelled in the arms and changes the costs" do
    opts = [experiment: :danger, set: :p1, nodes: 4, steps: 12, hold: 5, quiet: true, out: false]
    {:ok, c} = Select.run(opts ++ [cost: :comparisons])
    {:ok, o} = Select.run(opts)
    assert c.summary.sweep.arms |> Enum.all?(&String.ends_with?(&1, " (comparisons)"))
    refute Enum.any?(o.summary.sweep.arms, &String.contains?(&1, "comparisons"))
    assert Enum.all?(c.runs, &(&1.summary.domain == "sorting (comparisons)"))
    assert Enum.all?(o.runs, &(&1.summary.domain == "sorting"))
    # comparisons alone are fewer than comparisons + moves, for every solution
    x = TartarusImmune.Sorting.instance(:p1, 12_345, 1)

    for s <- TartarusImmune.Sorting.base_solutions(),
        do:
          assert(
            TartarusImmune.Sorting.Comparisons.score(s, x) < TartarusImmune.Sorting.score(s, x)
          )

    assert {:error, msg} = Select.run(opts ++ [cost: :time])
    assert msg =~ ":cost"
  end

  # The pre-registered configuration itself on one seed outside its 40 (999, the smoke
  # run disclosed in docs/immune.md): about 15 s on a quiet machine, a minute loaded.
  @tag :long
  @tag timeout: 600_000
  test "the pre-registered configuration runs: only the seeds deviate, QS wins every arm" do
    {:ok, r} = Select.run(experiment: :fig6_8, seed: 999, quiet: true, out: false)
    p = r.summary.preregistered
    assert p.deviations == [:seeds]
    assert r.summary.nodes == 50
    assert r.summary.winners_by_seed == %{"p4" => ["QS", "QS", "QS"]}
    # no sharing: nothing migrates; the 40 empty hosts never get an iPkt
    assert r.summary.arms["no_sharing"].migrations_mean == 0.0
    assert r.summary.arms["danger"].migrations_mean > 0
  end
end
