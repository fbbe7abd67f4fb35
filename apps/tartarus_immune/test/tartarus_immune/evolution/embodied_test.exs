defmodule TartarusImmune.Evolution.EmbodiedTest do
  use ExUnit.Case, async: true

  alias TartarusArena.World
  alias TartarusImmune.Evolution.Embodied

  doctest Embodied

  test "backing up earns no f_obs: the speed in Eqs. 7.1-7.3 is the forward speed" do
    alias TartarusImmune.Evolution.Objective
    # facing a wall 0.8 m ahead, from the middle of the arena, 20 steps of 0.1 s
    w0 =
      World.new(size: {2.0, 2.0}, seed: 1, noise: :none)
      |> World.add_robot(:r, x: 1.0, y: 1.0, theta: 0.0, tool: :pusher)

    trace = fn wheels ->
      {_, samples} =
        Enum.reduce(1..20, {w0, []}, fn _, {w, acc} ->
          w = World.step(w, %{r: wheels}, 0.1)
          {readings, w} = World.sense(w, :r)
          {w, [Embodied.sample(w, :r, readings) | acc]}
        end)

      samples
    end

    back = trace.({-1.0, -1.0})
    fwd = trace.({1.0, 1.0})
    assert Enum.all?(back, &(&1.v_trans == 0.0 and Objective.f_obs(&1) == 0.0))
    assert Enum.all?(fwd, &(&1.v_trans == 1.0 and Objective.f_obs(&1) > 0.0))
    assert Objective.fitness(:s1, fwd) > Objective.fitness(:s1, back)
    # S3 light off: f_antipuck pays driving on without a puck, not backing away
    assert Enum.all?(back, &(Objective.f_antipuck(&1) == 0.0))
  end

  test "b_puck is the colour sensor seeing yellow: a puck held head-on counts, one at the side of the pusher's U does not" do
    base = World.new(seed: 1, noise: :none) |> World.add_robot(:r, x: 1.0, y: 1.0, tool: :pusher)
    # touching the robot (radius 0.07) at `angle` off its heading
    at = fn angle -> {1.0 + 0.1 * :math.cos(angle), 1.0 + 0.1 * :math.sin(angle)} end

    puck = fn angle ->
      {x, y} = at.(angle)
      w = World.add_puck(base, 1, x: x, y: y)
      {readings, w} = World.sense(w, :r)
      {readings.puck_in_gripper, Embodied.sample(w, :r, readings).puck}
    end

    assert puck.(0.0) == {true, true}
    assert puck.(0.2) == {true, true}
    # in the capture zone (34 degrees), beside the colour sensor
    assert puck.(0.5) == {true, false}
    assert puck.(-0.5) == {true, false}
    assert puck.(1.2) == {false, false}
    {readings, w} = World.sense(base, :r)
    refute Embodied.sample(w, :r, readings).puck
  end

  test "the immune robot grows a repertoire, the monolithic one keeps one controller; same seed, same run" do
    {:ok, a} = Embodied.run(scenario: :s1, iterations: 40, test_episodes: 2, seed: 4)
    assert a.antibodies > 1 and length(a.curve) == 40
    assert Enum.all?(a.curve, &(&1.steps >= 1 and &1.steps <= 30))
    assert length(a.test_episodes) == 2 and a.test_success in [0.0, 0.5, 1.0]
    {:ok, b} = Embodied.run(scenario: :s1, iterations: 40, test_episodes: 2, seed: 4)
    assert a.curve == b.curve and a.test_episodes == b.test_episodes

    {:ok, m} =
      Embodied.run(scenario: :s1, design: :monolithic, iterations: 40, test_episodes: 1, seed: 4)

    assert m.antibodies == 1 and m.switches == 0
    # every period of the single controller runs to its full length
    assert Enum.all?(m.curve, &(&1.steps == 30))
  end

  test "S3: the light goes off, on and off again; antibodies are made for each light" do
    {:ok, r} = Embodied.run(scenario: :s3, iterations: 120, test_episodes: 1, seed: 2)
    [on, off] = r.light_switches
    assert on < off
    assert Enum.all?(r.curve, &(&1.light_on == (&1.iteration >= on and &1.iteration < off)))
    # with the light on the epitopes differ (light sensors), so new antibodies appear
    assert r.by_light.on >= 1 and r.by_light.off >= 1
    assert r.antibodies >= 2
    assert length(r.test_episodes) == 2
  end

  test "each evaluation follows an unscored recovery period; recovery 0 is the plain loop" do
    {:ok, r} =
      Embodied.run(
        scenario: :s1,
        iterations: 30,
        test_episodes: 1,
        seed: 5,
        trace: true,
        recovery: 20
      )

    scored = Enum.sum(Enum.map(r.curve, & &1.steps))
    # the robot drove the 20 recovery steps of every evaluation besides the scored ones
    # (more when a recovery left the antibody's region and the round was not evaluated)
    assert length(r.trajectory) == scored + 20 * (30 + r.unevaluated_rounds)

    {:ok, r0} =
      Embodied.run(
        scenario: :s1,
        iterations: 30,
        test_episodes: 1,
        seed: 5,
        trace: true
      )

    assert length(r0.trajectory) == Enum.sum(Enum.map(r0.curve, & &1.steps))
    assert r0.unevaluated_rounds == 0
    # the thesis's loop, without a recovery period, is the default
    assert Embodied.options(scenario: :s1).recovery == 0
  end

  test "the test re-selects as Algorithm 5 does or every period; both are reproducible" do
    opts = [scenario: :s1, iterations: 40, test_episodes: 3, seed: 6]
    {:ok, a} = Embodied.run(opts)
    {:ok, b} = Embodied.run(opts ++ [test_switch: :period])
    # same training (the test comes after it), possibly different test drives
    assert a.curve == b.curve
    assert {:ok, ^a} = Embodied.run(opts)
    assert {:error, message} = Embodied.run(opts ++ [test_switch: :never])
    assert message =~ "for key :test_switch"
  end

  test "the S2 arena never places a puck on another, on the robot or on the light" do
    o = Embodied.options(scenario: :s2)

    for seed <- 1..100 do
      {w, _} = Embodied.arena(%{o | seed: seed}, :rand.seed_s(:exsss, {seed, 9, 9}), true)
      pucks = Map.values(w.pucks)
      {rx, ry, _} = TartarusArena.World.pose(w, :robot)
      assert length(pucks) in 5..10

      for p <- pucks do
        assert :math.sqrt((p.x - rx) ** 2 + (p.y - ry) ** 2) >= 0.2
        assert :math.sqrt((p.x - 1.0) ** 2 + (p.y - 1.0) ** 2) >= 0.15

        for q <- pucks,
            q.id != p.id,
            do: assert(:math.sqrt((p.x - q.x) ** 2 + (p.y - q.y) ** 2) >= 0.06)
      end
    end
  end

  test "the reading of f_puck is an option: the product by default, the printed sum on request" do
    run = fn opts ->
      {:ok, r} = Embodied.run([scenario: :s2, iterations: 30, test_episodes: 0, seed: 3] ++ opts)
      r
    end

    product = run.([])
    assert run.(puck_reward: :product).curve == product.curve
    sum = run.(puck_reward: :sum)
    # the first evaluation runs the same controller on the same arena under both readings;
    # the sum pays every step's forward speed again (and a puck still), so it scores at
    # least as high
    [p1 | _] = product.curve
    [s1 | _] = sum.curve
    assert s1.steps == p1.steps and s1.fitness >= p1.fitness
    assert sum.curve != product.curve
    # S1 has no pucks: the reading changes nothing
    {:ok, a} = Embodied.run(scenario: :s1, iterations: 20, test_episodes: 0, seed: 3)

    {:ok, b} =
      Embodied.run(scenario: :s1, iterations: 20, test_episodes: 0, seed: 3, puck_reward: :sum)

    assert a.curve == b.curve
  end

  test "bad options are refused with the key named" do
    assert {:error, message} = Embodied.run(scenario: :s4)
    assert message =~ "for key :scenario"
    assert {:error, message} = Embodied.run(scenario: :s2, puck_reward: :max)
    assert message =~ "for key :puck_reward"
  end

  test "score: :total is the objective summed over the period (Eq. 7.1), :per_step divides it by the period's steps" do
    # the monolithic robot's periods are all `period` steps long, and the strategy only
    # compares fitnesses, so the two runs are the same run with the fitness scaled
    run = fn score ->
      {:ok, r} =
        Embodied.run(
          scenario: :s1,
          design: :monolithic,
          iterations: 12,
          test_episodes: 0,
          seed: 3,
          score: score
        )

      r
    end

    per_step = run.(:per_step)
    total = run.(:total)
    assert Embodied.options([]).score == :per_step

    for {a, b} <- Enum.zip(per_step.curve, total.curve) do
      assert a.steps == 30 and b.steps == 30
      assert_in_delta b.fitness, 30 * a.fitness, 1.0e-9
    end
  end

  test "the curve says, per evaluation, the epitope that chose, what the strategy proposed with which sigma, and the steps with a puck in view" do
    {:ok, r} = Embodied.run(scenario: :s2, iterations: 40, test_episodes: 0, seed: 1)

    for p <- r.curve do
      assert length(p.epitope) == 4
      assert p.kind in [:offspring, :champion]
      assert p.sigma >= 0.5 and p.sigma <= 4.0
      assert p.puck_steps in 0..p.steps
    end

    # an antibody's first evaluation is an offspring at the strategy's smallest sigma
    first = r.curve |> Enum.uniq_by(& &1.antibody)
    assert Enum.all?(first, &(&1.kind == :offspring and &1.sigma == 0.5))
  end
end
