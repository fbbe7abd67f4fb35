defmodule TartarusImmune.Evolution.InnerLoopTest do
  @moduledoc false
  use ExUnit.Case, async: true

  alias TartarusImmune.Evolution.{Embodied, Repertoire}

  @printed [loop: :while_in_region, min_period: 1, score: :total, puck_reward: :sum]

  defp run(opts) do
    {:ok, r} = Embodied.run([scenario: :s2, iterations: 40, test_episodes: 2, seed: 5] ++ opts)
    r
  end

  test "Algorithm 5's inner loop: a period that ends inside the region is followed by another of the same antibody, in the same iteration" do
    r = run(@printed)
    by_iteration = Enum.group_by(r.curve, & &1.iteration)
    # every iteration ran, and some ran more than one period
    assert map_size(by_iteration) == 40
    assert r.evaluations == length(r.curve) and r.evaluations > 40

    for {_, pts} <- by_iteration do
      # one antibody per iteration, periods numbered 1, 2, ...
      assert pts |> Enum.map(& &1.antibody) |> Enum.uniq() |> length() == 1
      assert Enum.map(pts, & &1.inner) == Enum.to_list(1..length(pts))
      assert length(pts) <= 10
      # every period but the last ran its 30 steps (it did not leave the region)
      assert Enum.all?(Enum.drop(pts, -1), &(&1.steps == 30))
    end

    assert r.training_steps == r.curve |> Enum.map(& &1.steps) |> Enum.sum()
  end

  test "loop: :once keeps one evaluation per iteration; max_inner bounds the inner loop" do
    once = run(Keyword.put(@printed, :loop, :once))
    assert once.evaluations == 40 and Enum.all?(once.curve, &(&1.inner == 1))
    assert once.capped_iterations == 0

    capped = run(Keyword.put(@printed, :max_inner, 2))
    assert capped.curve |> Enum.map(& &1.inner) |> Enum.max() <= 2
    assert capped.capped_iterations > 0
    # the evaluations per antibody add up to all evaluations, in both loops
    for r <- [once, capped, run(@printed)] do
      assert r.probes.evaluations_by_antibody |> Map.values() |> Enum.sum() == r.evaluations
    end
  end

  test "the monolithic robot evaluates once per iteration under either loop" do
    r = run([design: :monolithic] ++ @printed)
    assert r.evaluations == 40 and Enum.all?(r.curve, &(&1.steps == 30))
  end

  test "probes: puck antibodies are those whose paratope has the colour sensor on yellow" do
    r = run(@printed)
    p = r.probes

    puck =
      r.repertoire.antibodies
      |> Map.values()
      |> Enum.filter(&Embodied.puck_antibody?(&1.paratope))

    assert p.puck_antibodies == length(puck)

    assert p.puck_obstacle_antibodies ==
             Enum.count(puck, &(Enum.at(&1.paratope, 2) < 0.2))

    assert p.holds_puck_and_obstacle == p.puck_obstacle_antibodies > 0
    assert p.puck_ab_steps <= p.puck_steps
    assert p.episodes == 2
    assert p.wall_free_episodes in 0..2 and p.light_episodes in 0..2
    assert is_float(p.test_objective) and p.test_objective > p.test_objective_product

    # a champion's fitness starts where its first evaluation left it
    for ab <- puck do
      first = Enum.find(r.curve, &(&1.antibody == ab.id))
      assert first.champion_fitness == first.fitness
    end
  end

  test "probes on a made-up repertoire and episodes: structure, use, behaviours and the champion's gain" do
    es = fn f -> %TartarusImmune.Evolution.ES{champion: [], fitness: f} end

    rep = %Repertoire{
      epsilon: 0.4,
      shape: [4, 5, 2],
      antibodies: %{
        {:self, 1} => %{id: 1, paratope: [0.5, 0.5, 0.9, 7 / 9], es: es.(5.0), concentration: 1},
        {:self, 2} => %{id: 2, paratope: [0.5, 0.5, 0.9, 3 / 9], es: es.(4.0), concentration: 1},
        {:self, 3} => %{id: 3, paratope: [0.5, 0.5, 0.1, 3 / 9], es: es.(1.0), concentration: 1}
      }
    }

    pt = fn id, f, fwd ->
      %{antibody: id, fitness: f, champion_fitness: f, steps: 30, forward_steps: fwd}
    end

    # Ab3's champion (fitness 1.0) is its first period's, which ran stalled
    curve = [
      pt.(2, 1.0, 30),
      %{pt.(3, 1.0, 0) | champion_fitness: 2.0},
      pt.(2, 4.0, 30),
      pt.(1, 5.0, 20)
    ]

    ep = fn bumps, near, run, steps, ab ->
      %{
        light_on: true,
        bumps: bumps,
        reached_light: near,
        longest_puck_run: run,
        puck_steps: steps,
        puck_ab_steps: ab,
        objective: 1.0,
        objective_product: 0.5
      }
    end

    eps = [
      ep.(0, true, 25, 10, 9),
      ep.(3, false, 0, 10, 6),
      %{ep.(0, true, 0, 0, 0) | light_on: false}
    ]

    p = Embodied.probes(rep, curve, eps, %{})

    assert p.puck_antibodies == 2 and p.puck_obstacle_antibodies == 1 and
             p.holds_puck_and_obstacle

    assert p.evaluations_by_antibody == %{"1" => 1, "2" => 2, "3" => 1}
    assert p.puck_antibody_evaluations == 3
    assert p.puck_steps == 20 and p.puck_ab_steps == 15 and p.puck_use == 0.75
    # gains: Ab2 4 - 1 = 3, Ab3 1 - 2 = -1: mean 1
    assert p.puck_champion_gain == 1.0 and p.puck_champion_improved
    # two light-on episodes: each behaviour needs one of them
    assert p.episodes == 2
    assert {p.wall_free_episodes, p.light_episodes, p.puck_kept_episodes} == {1, 1, 1}
    refute p.fails_a_behaviour
    # the trace: one stalled period of four; Ab3, the wall's, set its champion stalled
    assert p.trace.stalled_share == 0.25 and p.trace.full_share == 1.0
    assert p.trace.champions == 3 and p.trace.champions_stalled == 1
    assert p.trace.wall_champions == 1 and p.trace.wall_champions_stalled == 1
    assert p.trace.fitness_stalled == 1.0 and p.trace.fitness_moving == 10.0 / 3
    p2 = Embodied.probes(rep, curve, [ep.(1, true, 25, 0, 0), ep.(2, true, 30, 0, 0)], %{})
    assert p2.wall_free_episodes == 0 and p2.fails_a_behaviour and p2.puck_use == nil
  end

  test "evaluation: :fixed runs every period its t' steps and checks the region only between periods" do
    region = run(@printed)
    fixed = run(@printed ++ [evaluation: :fixed])
    # stopped at once on leaving, some periods are short; with t' fixed none is
    assert Enum.any?(region.curve, &(&1.steps < 30))
    assert Enum.all?(fixed.curve, &(&1.steps == 30))
    assert fixed.training_steps == 30 * fixed.evaluations
    # the region still decides whether the iteration goes on: some iterations have one
    # period, some more
    sizes = fixed.curve |> Enum.frequencies_by(& &1.iteration) |> Map.values()
    assert Enum.any?(sizes, &(&1 == 1)) and Enum.any?(sizes, &(&1 > 1))
  end

  test "the behaviour probe: the antibody run with a puck held and an obstacle nearer than 20 cm, against the one run without" do
    rep = %Repertoire{epsilon: 0.4, shape: [4, 5, 2], antibodies: %{}}

    ep = fn near, far ->
      %{
        light_on: true,
        bumps: 0,
        reached_light: true,
        longest_puck_run: 0,
        puck_steps: 0,
        puck_ab_steps: 0,
        objective: 1.0,
        objective_product: 0.5,
        puck_near_by_antibody: near,
        puck_far_by_antibody: far
      }
    end

    # near steps: Ab4 4 + 3 = 7 of 10, far steps: Ab3 mostly
    p =
      Embodied.probes(
        rep,
        [],
        [ep.(%{4 => 4, 3 => 2}, %{3 => 20}), ep.(%{4 => 3, 3 => 1}, %{4 => 5})],
        %{}
      )

    assert {p.puck_near_steps, p.puck_far_steps} == {10, 25}
    assert {p.puck_near_antibody, p.puck_far_antibody} == {4, 3}
    assert p.holds_puck_obstacle_by_behaviour and p.puck_near_antibody_share == 0.7
    # the same antibody in both: no puck-with-obstacle antibody by behaviour
    same = Embodied.probes(rep, [], [ep.(%{3 => 2}, %{3 => 9})], %{})
    refute same.holds_puck_obstacle_by_behaviour
    # no puck held near an obstacle: none either
    none = Embodied.probes(rep, [], [ep.(%{}, %{3 => 9})], %{})
    refute none.holds_puck_obstacle_by_behaviour
    assert none.puck_near_antibody == nil and none.puck_near_antibody_share == nil
  end

  test "the behaviour probe counts the test's puck steps by whether an obstacle is nearer than 20 cm" do
    r = run(@printed ++ [test_episodes: 4])
    p = r.probes
    assert p.puck_near_steps + p.puck_far_steps == p.puck_steps
  end

  test "step_budget: training goes on until the scored steps reach the budget" do
    r = run(design: :monolithic, step_budget: 301, test_episodes: 0)
    # monolithic periods are 30 steps: 11 of them reach 301
    assert r.training_steps == 330 and r.evaluations == 11 and r.iterations == 11
  end

  test "the trace: stalled periods, and the champions they set" do
    r = run(@printed)
    t = r.probes.trace
    assert t.champions == map_size(r.repertoire.antibodies)
    assert t.champions_stalled <= t.champions and t.wall_champions_stalled <= t.wall_champions
    stalled = Enum.count(r.curve, &(&1.forward_steps * 2 < &1.steps))
    assert t.stalled_share == stalled / length(r.curve)
    assert Enum.all?(r.curve, &(&1.forward_steps in 0..&1.steps))
  end
end
