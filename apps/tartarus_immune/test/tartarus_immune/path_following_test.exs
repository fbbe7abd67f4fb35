defmodule TartarusImmune.PathFollowingTest do
  use ExUnit.Case, async: false

  alias TartarusArena.{PFA, Paths}
  alias TartarusImmune.{Node, Params, PathFollowing}
  alias TartarusImmune.PathFollowing.Experiment

  doctest TartarusImmune.PathFollowing
  doctest TartarusImmune.PathFollowing.Experiment.Summary
  doctest TartarusImmune.Node
  doctest TartarusImmune.IPkt

  describe "the domain" do
    test "an instance's features are its sub-path's, normalized, and the types are the paths'" do
      for {set, id} <- [p1: 1, p2: 2], seed <- [1, 2] do
        path = Paths.path(id, seed)

        for i <- 0..(PathFollowing.sets()[set] - 1) do
          inst = PathFollowing.instance(set, i, seed)
          sp = Enum.at(path.subpaths, i)
          assert PathFollowing.features(inst) == sp.features
          assert inst.type == sp.type
          assert length(sp.features) == PathFollowing.feature_count()
          assert Enum.all?(sp.features, &(&1 >= 0 and &1 <= 1))
          assert_in_delta inst.nominal, (sp.to - sp.from) / 0.25, 1.0e-9
        end
      end

      types = fn set ->
        for i <- 0..(PathFollowing.sets()[set] - 1), do: PathFollowing.instance(set, i, 1).type
      end

      assert types.(:p1) == [:sp_c, :sp_a, :sp_b, :sp_a]
      assert types.(:p2) == [:sp_c, :sp_a, :sp_d, :sp_b, :sp_a]
      assert PathFollowing.solutions() == TartarusArena.PFAs.all()
      assert PathFollowing.solution_name(PFA.A4) == "A4"
    end

    test "the score is a robot's run over the sub-path: a failure costs 12 nominal times" do
      straight = PathFollowing.instance(:p1, 0, 1)
      acute = PathFollowing.instance(:p2, 2, 1)
      assert straight.type == :sp_c and acute.type == :sp_d

      a1 = PathFollowing.score(PFA.A1, straight)
      a5 = PathFollowing.score(PFA.A5, straight)
      # bang-bang at full speed is faster on a straight than the PD controller at 0.75
      assert a1 >= 1.0 and a1 < a5
      # A2 spins in place at the acute turns' tips and loses the line; A1 keeps pivoting
      assert PathFollowing.score(PFA.A2, acute) == 12.0
      assert PathFollowing.score(PFA.A1, acute) < 12.0
      # deterministic
      assert PathFollowing.score(PFA.A1, straight) == a1
    end
  end

  describe "deferred interactions (Node.choose/3, Node.feedback/5)" do
    setup do
      %{p: Params.new!(mu: 0.8)}
    end

    test "an untried candidate is tried first; measured ones still compete", %{p: p} do
      fx = [0.7, 0.2, 0.0, 0.0]
      a = {1, %{sol: :a, fv: fx, tau: 10.0, zeta: 1.1, n: 3}}
      b = {2, %{sol: :b, fv: fx, tau: 10.0, zeta: 1.5, n: 3}}
      new = {3, %{sol: :c, fv: fx, tau: 10.0, zeta: nil, n: 0}}
      other = {4, %{sol: :d, fv: [0.3, 0.7, 0.0, 0.2], tau: 10.0, zeta: 0.5, n: 3}}

      d = Node.choose([a, b, new, other], fx, p)
      assert d.selected == 3 and d.solution == :c
      # the far iPkt (another sub-path type) is no candidate; the new one takes no part
      assert Enum.map(d.taus, &elem(&1, 0)) == [1, 2]
      [{1, ta}, {2, tb}] = d.taus
      assert ta > 10.0 and tb < 10.0

      d = Node.choose([a, b, other], fx, p)
      assert d.selected == 1 and d.dead == []
    end

    test "explore: :activation tries a new PFA only where no measured one is more activated",
         %{p: p} do
      fx = [0.7, 0.2, 0.0, 0.0]
      a = {1, %{sol: :a, fv: fx, tau: 20.0, zeta: 1.1, n: 3}}
      b = {2, %{sol: :b, fv: fx, tau: 5.0, zeta: 1.5, n: 3}}
      new = {3, %{sol: :c, fv: fx, tau: 10.0, zeta: nil, n: 0}}
      act = Map.put(p, :explore, :activation)

      # a is stimulated above the newcomer's tau_init: the network's choice runs
      d = Node.choose([a, b, new], fx, act)
      assert d.selected == 1 and d.explored == false

      # a drained by cloning, below the newcomer: the newcomer is tried
      drained = {1, %{sol: :a, fv: fx, tau: 6.0, zeta: 1.1, n: 3}}
      d = Node.choose([drained, new], fx, act)
      assert d.selected == 3 and d.explored == true

      # explore: false never tries it while a measured candidate exists; alone, it runs
      assert Node.choose([drained, new], fx, Map.put(p, :explore, false)).selected == 1
      assert Node.choose([new], fx, Map.put(p, :explore, false)).selected == 3
    end

    test "n_min: a loser with fewer measures survives suppression and counts as untried",
         %{p: p} do
      fx = [0.5, 0.3, 0.9, 0.7]
      a = {1, %{sol: :a, fv: fx, tau: 20.0, zeta: 1.0, n: 3}}
      b = {2, %{sol: :b, fv: fx, tau: 5.0, zeta: 2.0, n: 1}}

      assert Node.choose([a, b], fx, p).dead == [2]

      d = Node.choose([a, b], fx, Map.merge(p, %{n_min: 2, explore: false}))
      assert d.selected == 1 and d.dead == []

      d = Node.choose([a, b], fx, Map.put(p, :n_min, 2))
      assert d.selected == 2 and d.explored
    end

    test "a loser dies below tau_min; the selected one never dies when chosen", %{p: p} do
      fx = [0.5, 0.3, 0.9, 0.7]
      a = {1, %{sol: :a, fv: fx, tau: 20.0, zeta: 1.0, n: 3}}
      b = {2, %{sol: :b, fv: fx, tau: 5.0, zeta: 2.0, n: 3}}
      d = Node.choose([a, b], fx, p)
      assert d.selected == 1 and d.dead == [2]
    end

    test "feedback: kin take the measured cost, the selected clones within its queue", %{p: p} do
      fx = [0.5, 0.3, 0.9, 0.7]
      sel = {1, %{sol: :a, fv: fx, tau: 20.0, zeta: 1.0, n: 1}}
      kin = {2, %{sol: :a, fv: fx, tau: 6.0, zeta: 1.0, n: 1}}

      d = Node.feedback(sel, [sel, kin], fx, 2.0, Map.put(p, :q_current, 2))
      assert d.scores == %{1 => {1.5, 2}, 2 => {1.5, 2}}
      assert d.nc == 3 and d.tau_after == 5.0 and d.dead == []
      assert_in_delta d.psi_norm, 1.0, 1.0e-9

      # a full queue: no clone
      d = Node.feedback(sel, [sel], fx, 2.0, Map.put(p, :q_current, p.q_max))
      assert d.nc == 0 and d.tau_after == 20.0
    end
  end

  describe "the experiment" do
    @small [trials: 1, laps: 4, seed: 3, pfas: [PFA.A1, PFA.A3, PFA.A5], quiet: true]
    @roam [explore: :untried_first, sharing: true]

    @tag :tmp_dir
    test "lap_times_mean.svg: the mean of each lap over the trials with its 95 % interval, on whole laps",
         %{tmp_dir: dir} do
      {:ok, %{summary: s}} =
        Experiment.run([out: dir, trials: 2, laps: 3] ++ Keyword.drop(@small, [:trials, :laps]))

      svg = File.read!(Path.join(dir, "lap_times_mean.svg"))
      per_trial = s.lap_times["per_trial"]["path1"]

      drawn =
        Regex.scan(
          ~r/<g class="interval" data-x="(\d+)" data-lo="([^"]+)" data-hi="([^"]+)"><title>Path-1:/,
          svg,
          capture: :all_but_first
        )

      assert length(drawn) == 3

      for [lap, lo, hi] <- drawn do
        ci =
          TartarusTools.Stats.mean_ci(
            Enum.map(per_trial, &Enum.at(&1, String.to_integer(lap) - 1))
          )

        assert_in_delta elem(Float.parse(lo), 0), ci.lo, 1.0e-3
        assert_in_delta elem(Float.parse(hi), 0), ci.hi, 1.0e-3

        assert_in_delta ci.mean,
                        Enum.at(s.lap_times["mean"]["path1"], String.to_integer(lap) - 1),
                        1.0e-3
      end

      assert svg =~ "points: mean over 2 trials; error bars: 95 % confidence interval"
      assert svg =~ "seeds 3-4, 3 laps" and svg =~ "time per lap (s)"
      refute svg =~ ~r/text-anchor="middle">\d+\.5<\/text>/
    end

    @tag :tmp_dir
    test "on a small case (every new PFA tried at once, every iPkt roaming) the network's " <>
           "choice per sub-path type beats the exhaustive best where the laps measured it better, and the same seed gives the same numbers",
         %{tmp_dir: dir} do
      small = @small ++ @roam
      {:ok, a} = Experiment.run([out: dir] ++ small)
      {:ok, b} = Experiment.run([out: false] ++ small)
      s = a.summary
      drop = &Map.drop(&1, [:wall_seconds, :sim_speed_x])
      assert drop.(s) == drop.(b.summary)
      assert a.trials == b.trials

      assert s.exhaustive_best == %{
               "sp_a" => "A1",
               "sp_b" => "A1",
               "sp_c" => "A1",
               "sp_d" => "A1"
             }

      # in the laps a robot enters a sub-path as the previous PFA left it, and Path-2's
      # notch is tighter than Path-1's: A5 beats A1 on sp-b there (measured 1.31 against
      # 2.98: A1 overshoots the notch), though A1 is best alone
      m = s.measured_costs
      assert m["sp_b"]["A5"].mean < m["sp_b"]["A1"].mean
      assert s.best_pfa == %{"sp_a" => "A1", "sp_b" => "A5", "sp_c" => "A1", "sp_d" => "A1"}

      # each robot received the three PFAs, one per lap, and tried each
      [t] = a.trials
      assert Enum.sort(t.received.r1) == ["A1", "A3", "A5"]
      assert Enum.sort(t.received.r2) == ["A1", "A3", "A5"]
      assert t.counters.injected == 3 * 3 + 3 * 4
      assert t.counters.migrations > 0 and t.counters.born > 0 and t.counters.died > 0

      used = fn robot -> t.choices |> Enum.filter(&(&1.robot == robot)) |> Enum.map(& &1.pfa) end
      assert Enum.sort(Enum.uniq(used.(:r1))) == ["A1", "A3", "A5"]
      # the mappings travel: a robot ran a PFA before it received it itself
      first_run = fn robot, name ->
        Enum.find(t.choices, &(&1.robot == robot and &1.pfa == name)).lap
      end

      received_lap = fn robot, name -> Enum.find_index(t.received[robot], &(&1 == name)) + 1 end

      assert Enum.any?(
               for r <- [:r1, :r2],
                   n <- ["A1", "A3", "A5"],
                   do: first_run.(r, n) < received_lap.(r, n)
             )

      # lap times: 4 per path; on the last lap every sub-path the network chose for
      # (roaming iPkts may leave a crossing with no candidate: "kept") uses its type's best
      assert length(s.lap_times["trial1"]["path1"]) == 4
      last = Enum.filter(t.choices, &(&1.lap == 4 and &1.how != "kept"))

      assert last != [] and Enum.all?(last, &(&1.pfa == s.best_pfa[Atom.to_string(&1.type)])),
             inspect(last)

      for f <-
            ~w(lap_times.csv choices.csv best_pfa.csv lap_times_trial1.svg lap_times_mean.svg summary.json summary.md runs.csv),
          do: assert(File.exists?(Path.join(dir, f)), f)

      # the files show the mean curve, not every trial's (lap_times.csv has those), and
      # our figures beside the thesis's; the returned summary keeps everything
      json = dir |> Path.join("summary.json") |> File.read!() |> Tartarus.JSON.decode!()
      refute Map.has_key?(json, "lap_times")
      assert json["lap_times_mean"]["path1"] == s.lap_times["mean"]["path1"]

      assert hd(json["comparisons"]) == %{
               "metric" => "plateau lap, Path-1",
               "ours" => s.plateau_lap["path1"],
               "thesis" => 6
             }

      assert File.read!(Path.join(dir, "summary.md")) =~ "## Ours vs thesis"

      # the sweep: a row per trial, and its numbers are the trial's
      [_header, row] =
        dir |> Path.join("runs.csv") |> File.read!() |> String.split("\n", trim: true)

      last3 = t.lap_times[1] |> Enum.take(-3) |> TartarusTools.Stats.mean() |> Float.round(3)

      assert row ==
               Enum.join(
                 [
                   "pfa",
                   3,
                   last3,
                   Experiment.Summary.plateau_lap(t.lap_times[1]),
                   t.lost[1],
                   Enum.take(t.lap_times[2], -3) |> TartarusTools.Stats.mean() |> Float.round(3),
                   Experiment.Summary.plateau_lap(t.lap_times[2]),
                   t.lost[2]
                 ],
                 ","
               )

      assert s.sweep.aggregates["pfa"].last3_path1.n == 1

      {:ok, c} = Experiment.run(Keyword.merge(small, seed: 4, out: false, exhaustive: false))
      refute c.summary.lap_times == s.lap_times
    end

    test "exploration by activation, clones shared: every crossing has " <>
           "candidates, only clones travel, and the same seed gives the same numbers" do
      opts = [out: false, exhaustive: false, explore: :activation] ++ @small
      {:ok, a} = Experiment.run(opts)
      {:ok, b} = Experiment.run(opts)
      assert a.trials == b.trials
      assert a.summary.explore == :activation and a.summary.sharing == :clones
      [t] = a.trials

      # each robot's repertoire stays with it: never a sub-path without a candidate
      assert t.counters.no_candidate == 0
      assert Enum.all?(t.choices, &(&1.how in ["explored", "network"]))
      # only fresh clones move, each once
      assert t.counters.born > 0 and t.counters.migrations <= t.counters.born
      # lap 1 runs only the PFAs the robots received first (their own or the other's
      # clones); later laps exploit too
      firsts = [hd(t.received.r1), hd(t.received.r2)]
      lap1 = Enum.filter(t.choices, &(&1.lap == 1))
      assert lap1 != [] and Enum.all?(lap1, &(&1.pfa in firsts)), inspect(lap1)

      assert Enum.any?(t.choices, &(&1.how == "network" and &1.lap > 1))
      assert Map.has_key?(a.summary.plateau_lap_5pct, "path1")

      # without sharing nothing moves
      {:ok, c} = Experiment.run(opts ++ [sharing: false])
      assert hd(c.trials).counters.migrations == 0
    end

    test "the defaults: every PFA received is tried on every type of the robot's map, " <>
           "each crossing reports its put-backs and nudges, deterministic" do
      opts = [out: false, exhaustive: false] ++ @small
      {:ok, a} = Experiment.run(opts)
      {:ok, b} = Experiment.run(opts)
      assert a.trials == b.trials
      s = a.summary

      assert {s.explore, s.sharing, s.stream, s.stuck_after} ==
               {:untried_first, :clones, :once, 6.0}

      [t] = a.trials

      for robot <- [:r1, :r2] do
        rows = Enum.filter(t.choices, &(&1.robot == robot))
        types = rows |> Enum.map(& &1.type) |> Enum.uniq()

        for type <- types,
            do:
              assert(
                rows
                |> Enum.filter(&(&1.type == type))
                |> Enum.map(& &1.pfa)
                |> Enum.uniq()
                |> Enum.sort() == ["A1", "A3", "A5"],
                inspect({robot, type})
              )
      end

      assert Enum.all?(t.choices, &(is_integer(&1.put_back) and is_integer(&1.nudged)))
      assert Enum.all?(t.choices, &(&1.penalty == 5.0 * (&1.put_back + &1.nudged)))
      f = s.failures["path2"]

      assert f.put_back + f.nudged ==
               Enum.sum(Map.values(Map.new(t.lost, fn {k, v} -> {k, v} end))) - t.lost[1] +
                 f.put_back + f.nudged - t.lost[2]

      assert f.penalty_seconds == 5.0 * (f.put_back + f.nudged)
    end

    test "a lifelong stream injects again a PFA whose mapping died out; once, nothing " <>
           "after the last PFA" do
      opts = [out: false, exhaustive: false, laps: 6] ++ Keyword.delete(@small, :laps)
      {:ok, once} = Experiment.run(opts)
      {:ok, life} = Experiment.run(opts ++ [stream: :lifelong])
      [o] = once.trials
      [l] = life.trials
      assert o.counters.reinjected == 0
      assert l.counters.reinjected > 0
      assert l.counters.injected > o.counters.injected
      # the first three laps (the stream's first pass) are the same
      assert Enum.take(o.choices, 10) == Enum.take(l.choices, 10)
    end

    test "options are checked" do
      assert {:error, msg} = Experiment.run(stream: :forever)
      assert msg =~ "stream"
      assert {:error, msg} = Experiment.run(stuck_after: :never)
      assert msg =~ "stuck_after"
      assert {:error, msg} = Experiment.run(laps: 0)
      assert msg =~ "laps"
      assert {:error, msg} = Experiment.run(pfas: [Enum])
      assert msg =~ "pfas"
      assert {:error, msg} = Experiment.run(explore: 2)
      assert msg =~ "explore"
      assert {:error, msg} = Experiment.run(sharing: :all)
      assert msg =~ "sharing"
    end
  end
end
