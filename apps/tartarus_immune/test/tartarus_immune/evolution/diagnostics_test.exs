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
end
