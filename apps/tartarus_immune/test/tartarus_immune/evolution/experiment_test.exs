defmodule TartarusImmune.Evolution.ExperimentTest do
  use ExUnit.Case, async: true

  alias TartarusImmune.Evolution.Experiment

  doctest TartarusImmune.Evolution.Experiment.Robots3
  alias TartarusTools.Stats

  test "s1: both designs on the same seeds, compared by an exact Mann-Whitney U test" do
    {:ok, %{summary: s}} =
      Experiment.run(experiment: :s1, trials: 3, seed: 2, out: false, quiet: true, recovery: 5)

    # the thesis as printed is the default: the inner loop, stop at once, the sum
    assert s.recovery == 5 and s.period == 30 and s.min_period == 1
    assert s.puck_reward == "sum" and s.score == "total" and s.loop == "while_in_region"
    imm = s.arms["s1_immune"].test_success_by_trial
    mono = s.arms["s1_monolithic"].test_success_by_trial
    assert length(imm) == 3 and length(mono) == 3
    expected = Stats.mann_whitney(imm, mono)
    assert s.mann_whitney_u == expected.u
    assert s.p_value == Float.round(expected.p_value, 4)
    # three trials a side can never reach p < 0.05 (the smallest is 1 / C(6, 3) = 0.05)
    assert s.p_value >= 0.05 and s.immune_beats_monolithic == false
  end

  test "the step-matched baseline drives as many scored steps as the immune robot on the same seed; the probes' figures are per arm" do
    {:ok, %{summary: s}} =
      Experiment.run(experiment: :s1, trials: 2, seed: 3, out: false, quiet: true)

    imm = s.arms["s1_immune"]
    m = s.arms["s1_monolithic_matched"]
    assert m.antibodies == 1.0
    # a budget is met by the period that crosses it: at most one period (30 steps) more
    assert m.training_steps >= imm.training_steps and m.training_steps < imm.training_steps + 30
    assert s.arms["s1_monolithic"].training_steps == 200 * 30
    assert is_float(s.matched_objective_p_value) and is_float(s.objective_p_value)
    assert length(imm.test_objective_by_trial) == 2
    assert Map.has_key?(s.done_means, :structure)
  end

  test "the step-matched baseline is the default; --no-matched leaves it out" do
    {:ok, %{summary: s}} =
      Experiment.run(experiment: :s1, trials: 1, seed: 3, out: false, quiet: true, matched: false)

    refute Map.has_key?(s.arms, "s1_monolithic_matched")
    assert s.comparison == "iterations" and s.matched_objective_p_value == nil
  end

  @tag :tmp_dir
  test "s2_fixed: the fixed evaluation period t' as a labelled arm, each immune arm with its own step-matched baseline",
       %{tmp_dir: dir} do
    {:ok, %{summary: s, files: files}} =
      Experiment.run(experiment: :s2_fixed, trials: 1, seed: 3, out: dir, quiet: true)

    assert s.comparison == "step_matched"

    assert Enum.sort(Map.keys(s.arms)) ==
             ~w(s2_immune s2_immune_fixed s2_monolithic s2_monolithic_matched s2_monolithic_matched_fixed)

    fixed = s.arms["s2_immune_fixed"]
    # every period of the fixed arm is t' = 30 steps; its baseline drives as many
    assert fixed.training_steps == 30 * fixed.evaluations
    m = s.arms["s2_monolithic_matched_fixed"]

    assert m.training_steps >= fixed.training_steps and
             m.training_steps < fixed.training_steps + 30

    f = s.done_means.fixed_period
    assert is_boolean(f.learning) and is_boolean(f.stall_lower)
    assert is_boolean(f.puck_obstacle_by_behaviour_fixed)
    assert fixed.trials_puck_obstacle_by_behaviour in 0..1
    assert Enum.any?(files, &String.ends_with?(&1, "s2_fixed.svg"))
  end

  @tag :tmp_dir
  test "robots3_dynamic: static and dynamic arms on the same seeds, with the tests and the figure",
       %{tmp_dir: dir} do
    {:ok, %{summary: s, files: files}} =
      Experiment.run(
        experiment: :robots3_dynamic,
        trials: 1,
        seed: 3,
        out: dir,
        quiet: true,
        p: 0.3
      )

    assert Enum.sort(Map.keys(s.test_success)) ==
             ~w(broadcast broadcast_dynamic ipkt ipkt_dynamic none)

    assert s.links_up["broadcast"] == 1.0 and s.links_up["broadcast_dynamic"] < 1.0
    assert s.reached_per_publication["broadcast"] == 2.0
    assert s.reached_per_publication["broadcast_dynamic"] < 2.0
    assert Map.has_key?(s.p_values, "broadcast_dynamic > none")
    assert Enum.any?(files, &String.ends_with?(&1, "robots3_dynamic.svg"))
  end
end
