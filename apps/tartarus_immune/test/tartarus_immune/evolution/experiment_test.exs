defmodule TartarusImmune.Evolution.ExperimentTest do
  use ExUnit.Case, async: true

  alias TartarusImmune.Evolution.Experiment
  alias TartarusTools.Stats

  test "s1: both designs on the same seeds, compared by an exact Mann-Whitney U test" do
    {:ok, %{summary: s}} =
      Experiment.run(experiment: :s1, trials: 3, seed: 2, out: false, quiet: true, recovery: 5)

    assert s.recovery == 5 and s.period == 30 and s.min_period == 10
    # the product reading of f_puck is the default
    assert s.puck_reward == "product"
    imm = s.arms["s1_immune"].test_success_by_trial
    mono = s.arms["s1_monolithic"].test_success_by_trial
    assert length(imm) == 3 and length(mono) == 3
    expected = Stats.mann_whitney(imm, mono)
    assert s.mann_whitney_u == expected.u
    assert s.p_value == Float.round(expected.p_value, 4)
    # three trials a side can never reach p < 0.05 (the smallest is 1 / C(6, 3) = 0.05)
    assert s.p_value >= 0.05 and s.immune_beats_monolithic == false
  end
end
