defmodule TartarusImmune.MathsTest do
  use ExUnit.Case, async: true
  alias TartarusImmune.{Maths, Params}
  doctest TartarusImmune.Maths
  doctest TartarusImmune.Params

  @p Params.new!()

  test "Table 6.1 defaults" do
    assert {@p.mu, @p.sg_max, @p.l_span, @p.rho} == {0.5, 100, 2, 2}
    assert {@p.alpha, @p.delta, @p.gamma, @p.nu} == {0.4, 0.2, 1, 0.6}
    assert {@p.gamma_max, @p.tau_min, @p.tau_max, @p.q_max} == {1000, 5, 20, 5}
  end

  test "Eqs. 6.2-6.5: danger gradients with Table 6.1 (Sg_max 100, l_span 2)" do
    assert Maths.delta_sg(@p) == 50.0
    assert Maths.delta_life(@p) == 50.0
    assert Enum.map(0..3, &Maths.strength(&1, @p)) == [100.0, 50.0, 0.0, 0.0]
    assert Enum.map(0..3, &Maths.lifetime(&1, @p)) == [100.0, 50.0, 0.0, 0.0]
    # l_span 4, Sg_max 80: 80, 60, 40, 20, 0
    p = %{@p | l_span: 4, sg_max: 80}
    assert Enum.map(0..5, &Maths.strength(&1, p)) == [80.0, 60.0, 40.0, 20.0, 0.0, 0.0]
    # the platform's linear law is the same field
    assert Enum.map(0..2, &Tartarus.Signal.decay(:linear, 100, &1, 2)) ==
             Enum.map(0..2, &Maths.strength(&1, @p))
  end

  test "Eq. 6.6/6.7: affinity and threshold by hand" do
    # distance between (1,0,0,0) and (0,0,0,0) is 1: psi = 2 - 1 = 1 = psi_th, a candidate
    assert Maths.affinity([1, 0, 0, 0], [0, 0, 0, 0]) == 1.0
    assert Maths.threshold(4, @p) == 1.0
    assert Maths.recognizes?([1, 0, 0, 0], [0, 0, 0, 0], @p)
    # (0.5,0.5,0.5,0.5) vs (0,0,0,0): distance 1 -> psi 1
    assert Maths.affinity([0.5, 0.5, 0.5, 0.5], [0, 0, 0, 0]) == 1.0
    # (1,1,1,1) vs 0: distance 2 -> psi 0 (the minimum for normalized vectors)
    assert Maths.affinity([1, 1, 1, 1], [0, 0, 0, 0]) == 0.0
    # 3-4-5: (0.3, 0.4) in 2-D: psi = sqrt(2) - 0.5
    assert_in_delta Maths.affinity([0.3, 0.4], [0, 0]), :math.sqrt(2) - 0.5, 1.0e-12
    assert Maths.candidates([0, 0, 0, 0], [[0.6, 0.8, 0, 0], [0.6, 0.81, 0, 0]], @p) == [0]
  end

  test "Eqs. 6.8-6.10: one interaction by hand" do
    # psi(y1, y2) = 2 - 0.5 = 1.5; tau1 = 10, tau2 = 8; y1 is better.
    # Sti_1^2 = 1.5 + 0.4 * 8 = 4.7; Sup_2^1 = 1 * 1.5 + 0.2 * 10 = 3.5
    assert_in_delta Maths.stimulation(1.5, 8, @p), 4.7, 1.0e-12
    assert_in_delta Maths.suppression(1.5, 10, @p), 3.5, 1.0e-12
    assert Maths.activation(10, 4.7, 0) == 14.7

    [a, b] =
      Maths.interact(
        [%{fv: [0, 0, 0, 0], tau: 10, cost: 1}, %{fv: [0.3, 0.4, 0, 0], tau: 8, cost: 2}],
        @p
      )

    assert_in_delta a.tau, 14.7, 1.0e-12
    assert_in_delta b.tau, 4.5, 1.0e-12
  end

  test "Eq. 6.10 over three members, synchronous, capped at tau_max" do
    # all at the same FV: psi = 2 between any pair. costs 1 < 2 < 3; taus 10, 10, 18.
    ms = [
      %{fv: [0, 0, 0, 0], tau: 10, cost: 1},
      %{fv: [0, 0, 0, 0], tau: 10, cost: 2},
      %{fv: [0, 0, 0, 0], tau: 18, cost: 3}
    ]

    [a, b, c] = Maths.interact(ms, @p)
    # a: Sti from b (2 + 4) and c (2 + 7.2) = 15.2 -> 25.2, capped 20
    assert_in_delta a.sti, 15.2, 1.0e-12
    assert a.tau == 20.0
    # b: Sti from c (9.2), Sup from a (2 + 2) -> 10 + 9.2 - 4 = 15.2
    assert_in_delta b.tau, 15.2, 1.0e-12
    # c: Sup from a (4) and b (4) -> 10
    assert_in_delta c.tau, 10.0, 1.0e-12
    # equal costs do not interact
    assert [%{tau: 7.0}, %{tau: 7.0}] =
             Maths.interact([%{fv: [0], tau: 7, cost: 3}, %{fv: [1], tau: 7, cost: 3}], @p)

    assert Maths.select([%{tau: 1, cost: 1}, %{tau: 2, cost: 9}]) == 1
  end

  test "Eqs. 6.11-6.13: cloning and the queue brake" do
    p = %{@p | nc_cap: :none}
    # space 5 - 1 = 4; NC = 4 * 15 / 20 = 3; tau after = 15 - 3 * 5 = 0
    assert Maths.cloning_space(5, 1) == 4
    assert Maths.clones(15, 1, p) == 3
    assert Maths.after_cloning(15, 3, p) == 0.0
    # with the default cap the parent keeps tau_min: at most (15 - 5) / 5 = 2
    assert Maths.clones(15, 1, @p) == 2
    # a full queue (or an overfull one) blocks cloning whatever the activation
    assert Maths.clones(20, 5, p) == 0
    assert Maths.clones(20, 9, p) == 0
    # rounding choices: space 2, tau 13 -> 1.3
    assert Maths.clones(13, 3, %{p | nc_round: :floor}) == 1
    assert Maths.clones(13, 3, %{p | nc_round: :ceil}) == 2
    assert Maths.clones(13, 3, %{p | nc_round: :round}) == 1
  end

  test "Eqs. 6.14-6.15: affinity-proportional Gaussian hypermutation" do
    # psi_norm 1 (identical) -> lambda = e^-2; psi_norm 0 -> 1
    assert_in_delta Maths.mutation_rate(1.0, @p), :math.exp(-2), 1.0e-12
    assert Maths.mutation_rate(0.0, @p) == 1.0
    # nu 0.6: sd = sqrt(0.6); z = 0.5, psi_norm 0.5: delta = e^-1 * sqrt(0.6) * 0.5
    d = :math.exp(-1) * :math.sqrt(0.6) * 0.5
    [x] = Maths.hypermutate([0.2], 0.5, [0.5], @p)
    assert_in_delta x, 0.2 + d, 1.0e-12
    # a better-matched parent mutates less
    [hi] = Maths.hypermutate([0.5], 0.9, [1.0], @p)
    [lo] = Maths.hypermutate([0.5], 0.1, [1.0], @p)
    assert hi - 0.5 < lo - 0.5
    assert Maths.hypermutate([0.9], 0.0, [3.0], %{@p | clamp_fv: false}) |> hd() > 1.0
  end

  test "Eqs. 6.16-6.17: apoptosis by hops or activation" do
    assert Maths.life(0, @p) == 1000
    assert Maths.life(999, @p) == 1
    assert Maths.life(1000, @p) == 0
    assert Maths.apoptosis?(Maths.life(1000, @p), 20, @p)
    refute Maths.apoptosis?(Maths.life(999, @p), 5, @p)
    assert Maths.apoptosis?(Maths.life(10, @p), 4.99, @p)

    assert Maths.survivors(
             [
               %{gamma: 1, tau: 5},
               %{gamma: 0, tau: 20},
               %{gamma: 9, tau: 1},
               %{gamma: 2, tau: 8}
             ],
             @p
           ) == [0, 3]
  end
end
