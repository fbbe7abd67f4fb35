defmodule TartarusImmune.Evolution.DiagnosticsTest do
  use ExUnit.Case, async: true

  alias TartarusImmune.Evolution.Diagnostics

  doctest Diagnostics

  test "the S1 test is passable: hand-made phototaxis passes, driving straight into a wall fails" do
    c = Diagnostics.controllers()
    assert Diagnostics.ceiling(:s1, c.phototaxis, episodes: 5).success == 1.0
    straight = Diagnostics.ceiling(:s1, c.straight, episodes: 5)
    assert straight.success == 0.0
    # it ends pressed against a wall
    assert Enum.all?(straight.episodes, &(&1.final_stall > 0))
  end

  test "S2: pushing pucks towards the light by hand passes test episodes; circling passes none" do
    c = Diagnostics.controllers()
    pusher = Diagnostics.ceiling(:s2, c.wander_phototaxis, episodes: 10)
    assert pusher.success >= 0.2
    # with pucks sliding along walls and pushing each other, few episodes end stalled
    assert Enum.count(pusher.episodes, &(&1.final_stall > 0)) <= 2
    assert Diagnostics.ceiling(:s2, c.circle, episodes: 10).success == 0.0
    # taking a puck met to the light and carrying it round there passes at least as many
    # (40 episodes: 0.775 against 0.675, docs/evolution.md)
    assert Diagnostics.ceiling(:s2, c.deliver, episodes: 10).success >= pusher.success

    # under the product the circle still earns f_puck: it sweeps pucks into its pusher and
    # carries them round
    assert Diagnostics.fitness(:s2, c.circle, episodes: 5, puck_reward: :product) >
             Diagnostics.fitness(:s1, c.circle, episodes: 5)
  end

  test "Eq. 7.2 under both readings: delivering pucks to the light scores highest of the hand-made controllers, but under the product orbiting the light whatever the pucks comes within 0.05" do
    c = Diagnostics.controllers()

    for r <- [:sum, :product] do
      f = fn ctrl -> Diagnostics.fitness(:s2, ctrl, episodes: 20, puck_reward: r) end
      deliver = f.(c.deliver)
      assert deliver > f.(c.circle)
      assert deliver > f.(c.wander_phototaxis)
      assert deliver > f.(c.phototaxis)
      assert deliver > f.(c.orbit)
      if r == :product, do: assert(deliver - f.(c.orbit) < 0.05)
    end

    # S1: orbiting the light beats circling anywhere and plain phototaxis
    assert Diagnostics.fitness(:s1, c.orbit, episodes: 10) >
             Diagnostics.fitness(:s1, c.phototaxis, episodes: 10)

    assert Diagnostics.fitness(:s1, c.orbit, episodes: 10) >
             Diagnostics.fitness(:s1, c.circle, episodes: 10)
  end

  test "a recovery period makes one evaluation rank controllers more reliably" do
    plain = Diagnostics.ordering(period: 30, recovery: 0, runs: 3, evaluations: 60)
    recovered = Diagnostics.ordering(period: 30, recovery: 20, runs: 3, evaluations: 60)

    assert recovered.beats[{:phototaxis, :straight}] > plain.beats[{:phototaxis, :straight}]
    assert recovered.beats[{:avoid, :straight}] > plain.beats[{:avoid, :straight}]
    assert plain.beats[{:phototaxis, :avoid}] + plain.beats[{:avoid, :phototaxis}] <= 1.0
  end

  test "S2 evaluation by evaluation: Eq. 7.2 pays carrying a puck towards the light more than carrying it away, in the periods that start with a puck" do
    c = Diagnostics.controllers()
    clamp = fn xs -> Enum.map(xs, &max(-1.0, min(1.0, &1))) end

    # deliver's branch without a puck, and with a puck steering away from the light
    away = fn [ll, lr, us, col] ->
      cond do
        col >= 0.5 and us < 0.2 -> [-0.5, 0.5]
        col >= 0.5 -> [1.0, 1.0]
        true -> clamp.([1.0 + 4 * (ll - lr), 1.0 - 4 * (ll - lr)])
      end
    end

    to_light = Diagnostics.windows(:s2, c.deliver, episodes: 5)
    from_light = Diagnostics.windows(:s2, away, episodes: 5)
    assert to_light.puck.periods > 0 and from_light.puck.periods > 0
    assert to_light.puck.fitness > from_light.puck.fitness
    # the puck is kept through the periods that start with one
    assert to_light.puck.puck_share > 0.9
    # and those periods pay more per step than the periods without a puck
    assert to_light.puck.fitness > to_light.no_puck.fitness
  end

  test "the puck sub-task on its own: the same seed gives the same strategy and test" do
    a = Diagnostics.puck_subtask(evaluations: 8, seed: 2, episodes: 2)
    assert a == Diagnostics.puck_subtask(evaluations: 8, seed: 2, episodes: 2)
    assert a.improvements in 1..8
    assert a.test_success in [0.0, 0.5, 1.0]
    # each proposal judged on the mean of two puck periods: another run
    b = Diagnostics.puck_subtask(evaluations: 8, seed: 2, episodes: 2, repeats: 2)
    assert b.improvements in 1..8
    assert b != a
  end
end
