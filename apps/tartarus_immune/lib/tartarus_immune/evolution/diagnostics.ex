defmodule TartarusImmune.Evolution.Diagnostics do
  @moduledoc """
  Measurements behind the choices of `TartarusImmune.Evolution.Embodied` (docs/evolution.md,
  "Why learning was weak"): what the test asks of a controller, and how well one
  evaluation period tells a better controller from a worse one on a moving robot.

    * `controllers/0` - hand-made controllers on the same four normalized inputs as the
      evolved 4-5-2 networks (`[light_left, light_right, ultrasonic, colour]` to two wheel
      commands);
    * `ceiling/3` - the test success of a fixed controller (the test of `Embodied`);
    * `fitness/3` - the mean per-step objective (Eqs. 7.1-7.3) a fixed controller earns
      over such episodes: whether the fitness points where the test does;
    * `ordering/1` - how often a single evaluation ranks one controller above another
      when controllers take turns on one robot, each evaluation starting where the last
      one left the robot (as in the (1+1)-online strategy), for a given evaluation period
      and recovery period.

  Everything is seeded: the same options give the same numbers.

      iex> alias TartarusImmune.Evolution.Diagnostics
      iex> [l, r] = Diagnostics.controllers().phototaxis.([0.2, 0.4, 1.0, 0.78])
      iex> r < l
      true
  """

  alias TartarusArena.World
  alias TartarusImmune.Evolution.{Embodied, ES, NeuralNet, Objective}

  @shape [4, 5, 2]

  @typedoc "A fixed controller: normalized epitope to `[left, right]` wheel commands."
  @type controller :: ([float()] -> [float()])

  @doc """
  Hand-made controllers:

    * `:phototaxis` - turn towards the brighter light sensor, turn in place when the
      ultrasonic reads under 0.2 (40 cm): phototaxis with obstacle avoidance;
    * `:avoid` - straight on, turn in place under 0.2: obstacle avoidance only;
    * `:straight` - full speed ahead, whatever the sensors say;
    * `:wander_phototaxis` - obstacle avoidance, and phototaxis while the colour sensor
      sees a puck in the gripper (S2's sub-tasks by hand);
    * `:circle` - left wheel full, right wheel 0.6, whatever the sensors say: a tight
      circle at speed;
    * `:orbit` - phototaxis at full speed with a bias to the left that grows with the
      light, turning in place under 0.2: it goes to the light and circles round it (S1's
      "move towards the light source and then stay near it"), whatever the pucks;
    * `:deliver` - full speed ahead with obstacle avoidance, and `:orbit`'s steering
      (a stronger bias) while the colour sensor sees a puck: a puck met is taken to the
      light and carried round it there.
  """
  @spec controllers() :: %{atom() => controller()}
  def controllers do
    photo = fn ll, lr ->
      k = 4 * (lr - ll)
      [0.7 + k, 0.7 - k]
    end

    orbit = fn ll, lr, bias ->
      t = 4 * (lr - ll) - bias * (ll + lr)
      Enum.map([1.0 + t, 1.0 - t], &max(-1.0, min(1.0, &1)))
    end

    %{
      orbit: fn [ll, lr, us, _c] -> if us < 0.2, do: [-0.5, 0.5], else: orbit.(ll, lr, 0.3) end,
      deliver: fn [ll, lr, us, c] ->
        cond do
          c < 0.5 -> orbit.(ll, lr, 0.6)
          us < 0.2 -> [-0.5, 0.5]
          true -> [1.0, 1.0]
        end
      end,
      phototaxis: fn [ll, lr, us, _c] -> if us < 0.2, do: [-0.5, 0.5], else: photo.(ll, lr) end,
      avoid: fn [_ll, _lr, us, _c] -> if us < 0.2, do: [-0.5, 0.5], else: [0.7, 0.7] end,
      straight: fn _ -> [1.0, 1.0] end,
      circle: fn _ -> [1.0, 0.6] end,
      wander_phototaxis: fn [ll, lr, us, c] ->
        cond do
          c < 0.5 -> photo.(ll, lr)
          us < 0.2 -> [-0.5, 0.5]
          true -> [0.7, 0.7]
        end
      end
    }
  end

  @doc """
  The test success (0..1) of `controller` in `scenario`'s test (`Embodied`), over
  `episodes` episodes (default 40) from poses drawn from `seed` (default 1). Returns
  `%{success, episodes}` (each episode's outcome, as in `Embodied.run/1`).
  """
  @spec ceiling(:s1 | :s2 | :s3, controller(), keyword()) :: %{
          success: float(),
          episodes: [map()]
        }
  def ceiling(scenario, controller, opts \\ []) do
    o =
      Embodied.options(
        scenario: scenario,
        test_episodes: Keyword.get(opts, :episodes, 40),
        seed: Keyword.get(opts, :seed, 1)
      )

    {success, episodes, _} =
      Embodied.test_repertoire(o, controller, :rand.seed_s(:exsss, {o.seed, 9, 9}))

    %{success: success, episodes: episodes}
  end

  @doc """
  The mean per-step objective of `scenario` (`TartarusImmune.Evolution.Objective`, on the
  samples `Embodied` scores) that `controller` earns over `episodes` episodes of 30 s
  (default 20) from the test's poses (light on), drawn from `seed` (default 1), with
  `f_puck` read as `puck_reward` (`:product`, the default, or `:sum`).

      iex> alias TartarusImmune.Evolution.Diagnostics
      iex> Diagnostics.fitness(:s1, Diagnostics.controllers().straight, episodes: 2) < 1.0
      true
  """
  @spec fitness(:s1 | :s2 | :s3, controller(), keyword()) :: float()
  def fitness(scenario, controller, opts \\ []) do
    n = Keyword.get(opts, :episodes, 20)
    seed = Keyword.get(opts, :seed, 1)
    reading = Objective.puck_reward!(opts)
    o = Embodied.options(scenario: scenario, seed: seed)

    {total, _} =
      Enum.reduce(1..n, {0.0, :rand.seed_s(:exsss, {seed, 9, 9})}, fn _, {acc, rng} ->
        {world, rng} = Embodied.arena(o, rng, true)
        {_, samples} = drive(world, controller, 300, true)
        {acc + Objective.fitness(scenario, samples, puck_reward: reading) / 300, rng}
      end)

    Float.round(total / n, 3)
  end

  @doc """
  Controllers take turns on one S1 robot: each evaluation picks one of `controllers` (a
  keyword list of name and controller, default `:phototaxis`, `:avoid`, `:straight`) at
  random, runs it `recovery` steps unscored, then `period` steps scored with Eq. 7.1 (per
  step, as `Embodied` scores), from wherever the previous evaluation left the robot.
  Options: `period` (30), `recovery` (0), `evaluations` per run (120), `runs` (10, seeds
  1..runs), `controllers`.

  Returns `%{mean: name => mean fitness per step, beats: {a, b} => the probability that
  an evaluation of a scores higher than one of b}` for every ordered pair.
  """
  @spec ordering(keyword()) :: %{mean: map(), beats: map()}
  def ordering(opts \\ []) do
    period = Keyword.get(opts, :period, 30)
    recovery = Keyword.get(opts, :recovery, 0)
    n = Keyword.get(opts, :evaluations, 120)
    c = controllers()

    ctrls =
      Keyword.get(opts, :controllers,
        phototaxis: c.phototaxis,
        avoid: c.avoid,
        straight: c.straight
      )

    o = Embodied.options(scenario: :s1)

    evals =
      for seed <- 1..Keyword.get(opts, :runs, 10), reduce: [] do
        acc ->
          {world, _} = Embodied.arena(%{o | seed: seed}, :rand.seed_s(:exsss, {seed, 5, 5}), true)
          rng = :rand.seed_s(:exsss, {seed, 1, 1})

          {_, _, out} =
            Enum.reduce(1..n, {world, rng, acc}, fn _, {w, rng, out} ->
              {u, rng} = :rand.uniform_s(length(ctrls), rng)
              {name, f} = Enum.at(ctrls, u - 1)
              {w, _} = drive(w, f, recovery, false)
              {w, samples} = drive(w, f, period, true)
              {w, rng, [{name, Objective.fitness(:s1, samples) / period} | out]}
            end)

          out
      end

    by = Enum.group_by(evals, &elem(&1, 0), &elem(&1, 1))

    %{
      mean: Map.new(by, fn {k, xs} -> {k, Float.round(TartarusTools.Stats.mean(xs), 3)} end),
      beats:
        for {a, xs} <- by, {b, ys} <- by, a != b, into: %{} do
          wins = for x <- xs, y <- ys, x > y, reduce: 0, do: (k -> k + 1)
          {{a, b}, Float.round(wins / (length(xs) * length(ys)), 3)}
        end
    }
  end

  @doc """
  How `scenario`'s objective scores `controller` *evaluation by evaluation*, as the
  immune learner sees it: `controller` drives `episodes` episodes of 30 s from the test's
  poses (light on, seed `seed`, default 1), cut into evaluation periods by `Embodied`'s
  training rule (the epitope at a period's start is the paratope; the period ends when
  the epitope leaves its active region of radius `epsilon`, default the scenario's, after
  at least `min_period` steps (10), or after `period` steps (30)). Returns, for the
  periods that start with a puck in the colour sensor's view (`:puck`) and the others
  (`:no_puck`): how many there were, their mean per-step fitness (as `Embodied` scores a
  period) and its standard deviation over the periods, their mean length in steps, and the mean share of their steps with a puck in
  view; and `:light_gain`, the mean change of `f_light` from a puck period's first step
  to its last (whether the periods that carry a puck carry it towards the light).

      iex> alias TartarusImmune.Evolution.Diagnostics
      iex> w = Diagnostics.windows(:s2, Diagnostics.controllers().straight, episodes: 1)
      iex> w.no_puck.periods > 0
      true
  """
  @spec windows(:s1 | :s2 | :s3, controller(), keyword()) :: map()
  def windows(scenario, controller, opts \\ []) do
    n = Keyword.get(opts, :episodes, 20)
    seed = Keyword.get(opts, :seed, 1)
    reading = Objective.puck_reward!(opts)
    o = Embodied.options(scenario: scenario, seed: seed)
    eps = Keyword.get(opts, :epsilon, o.epsilon)
    min_p = Keyword.get(opts, :min_period, 10)
    period = Keyword.get(opts, :period, 30)

    {periods, _} =
      Enum.reduce(1..n, {[], :rand.seed_s(:exsss, {seed, 9, 9})}, fn _, {acc, rng} ->
        {world, rng} = Embodied.arena(o, rng, true)
        {cut(world, controller, 300, {eps, min_p, period}, scenario, reading, acc), rng}
      end)

    by = Enum.group_by(periods, & &1.puck_start)

    summary = fn ps ->
      k = max(length(ps), 1)

      %{
        periods: length(ps),
        fitness: Float.round(Enum.sum(Enum.map(ps, & &1.fitness)) / k, 3),
        fitness_sd: sd_3(Enum.map(ps, & &1.fitness)),
        steps: Float.round(Enum.sum(Enum.map(ps, & &1.steps)) / k, 1),
        puck_share: Float.round(Enum.sum(Enum.map(ps, & &1.puck_share)) / k, 3)
      }
    end

    puck = Map.get(by, true, [])

    %{
      puck: summary.(puck),
      no_puck: summary.(Map.get(by, false, [])),
      light_gain: Float.round(Enum.sum(Enum.map(puck, & &1.light_gain)) / max(length(puck), 1), 3)
    }
  end

  @doc """
  How many evaluations the (1+1)-online strategy needs to learn S2's puck sub-task on its
  own: one 4-5-2 network (random weights, `Embodied`'s strategy options, or `es`) drives
  only while the colour sensor sees a puck; the rest of the time a fixed hand-made branch
  drives (full speed ahead, turning in place under 0.2 on the ultrasonic: `:deliver`'s
  branch without a puck), so the robot meets pucks far more often than a learning robot.
  Each evaluation starts when a puck comes into view and ends by `Embodied`'s training
  rule (the epitope leaves the active region of radius 0.4 around the epitope it started
  with, after at least 10 steps, or 30 steps); its fitness is Eq. 7.2 (product) per
  step (with `repeats: k`, default 1, each proposal drives k puck periods in a row and
  its fitness is their mean: `evaluations` proposals, k times as many periods). After
  `evaluations` (default 200) evaluations from seed `seed` (1), the champion
  takes the puck branch of a controller whose other branch is the fixed one, and that
  controller sits S2's test (`ceiling/3`, `episodes`, default 20). Returns
  `%{fitness, improvements, test_success}` (the champion's last measured fitness, how
  many offspring replaced it, the test success).
  """
  @spec puck_subtask(keyword()) :: %{
          fitness: float(),
          improvements: non_neg_integer(),
          test_success: float()
        }
  def puck_subtask(opts \\ []) do
    n = Keyword.get(opts, :evaluations, 200)
    seed = Keyword.get(opts, :seed, 1)
    o = Embodied.options(scenario: :s2, seed: seed)
    es_opts = Keyword.get(opts, :es, o.es)
    rng = :rand.seed_s(:exsss, {seed, 42, 1})
    {world, rng} = Embodied.arena(o, rng, true)
    {net, rng} = NeuralNet.random(@shape, rng)

    repeats = Keyword.get(opts, :repeats, 1)

    {es, _, _} =
      Enum.reduce(1..n, {ES.new(net, es_opts), world, rng}, fn _, {es, w, rng} ->
        {kind, cand, rng} = ES.propose(es, rng)

        {w, fs} =
          Enum.reduce(1..repeats, {w, []}, fn _, {w, fs} ->
            w = until_puck(w, 0)
            {r, w} = World.sense(w, :robot)
            {w, samples} = puck_period(w, cand, World.normalize(r), 1, [])
            {w, [Objective.fitness(:s2, samples) / length(samples) | fs]}
          end)

        {ES.tell(es, {kind, cand}, Enum.sum(fs) / repeats), w, rng}
      end)

    ctrl = fn [_, _, _, c] = ep ->
      if c < 0.5, do: NeuralNet.forward(@shape, es.champion, ep), else: ahead(ep)
    end

    %{
      fitness: Float.round(es.fitness * 1.0, 3),
      improvements: es.improvements,
      test_success: ceiling(:s2, ctrl, episodes: Keyword.get(opts, :episodes, 20)).success
    }
  end

  defp ahead([_ll, _lr, us, _c]), do: if(us < 0.2, do: [-0.5, 0.5], else: [1.0, 1.0])

  # The fixed branch drives until the colour sensor sees a puck (at most 300 s).
  defp until_puck(w, k) when k > 3000, do: w

  defp until_puck(w, k) do
    {r, w} = World.sense(w, :robot)

    if r.colour == 3,
      do: w,
      else:
        until_puck(World.step(w, %{robot: List.to_tuple(ahead(World.normalize(r)))}, 0.1), k + 1)
  end

  defp puck_period(w, net, para, k, samples) do
    {r, w} = World.sense(w, :robot)
    [l, rr] = NeuralNet.forward(@shape, net, World.normalize(r))
    w = World.step(w, %{robot: {l, rr}}, 0.1)
    {next, w} = World.sense(w, :robot)
    samples = [Embodied.sample(w, :robot, next) | samples]

    if k >= 30 or (k >= 10 and dist(World.normalize(next), para) > 0.4),
      do: {w, samples},
      else: puck_period(w, net, para, k + 1, samples)
  end

  defp cut(_world, _f, left, _rule, _sc, _reading, acc) when left <= 0, do: acc

  defp cut(world, f, left, {eps, min_p, period} = rule, sc, reading, acc) do
    {r, world} = World.sense(world, :robot)
    para = World.normalize(r)

    {world, samples} =
      Enum.reduce_while(1..min(period, left), {world, []}, fn k, {w, samples} ->
        {r, w} = World.sense(w, :robot)
        [l, rr] = f.(World.normalize(r))
        w = World.step(w, %{robot: {l, rr}}, 0.1)
        {next, w} = World.sense(w, :robot)
        samples = [Embodied.sample(w, :robot, next) | samples]
        out = k >= min_p and dist(World.normalize(next), para) > eps
        if out, do: {:halt, {w, samples}}, else: {:cont, {w, samples}}
      end)

    steps = length(samples)
    ordered = Enum.reverse(samples)

    p = %{
      puck_start: r.colour == 3,
      steps: steps,
      fitness: Objective.fitness(sc, samples, puck_reward: reading) / steps,
      puck_share: Enum.count(samples, & &1.puck) / steps,
      light_gain: Objective.f_light(List.last(ordered)) - Objective.f_light(hd(ordered))
    }

    cut(world, f, left - steps, rule, sc, reading, [p | acc])
  end

  defp sd_3(xs) do
    case TartarusTools.Stats.sd(xs) do
      nil -> 0.0
      sd -> Float.round(sd, 3)
    end
  end

  defp dist(a, b),
    do: a |> Enum.zip(b) |> Enum.reduce(0.0, fn {x, y}, s -> s + (x - y) ** 2 end) |> :math.sqrt()

  defp drive(world, f, steps, score) do
    Enum.reduce(1..steps//1, {world, []}, fn _, {w, samples} ->
      {r, w} = World.sense(w, :robot)
      [l, rr] = f.(World.normalize(r))
      w = World.step(w, %{robot: {l, rr}}, 0.1)
      {next, w} = World.sense(w, :robot)
      {w, if(score, do: [Embodied.sample(w, :robot, next) | samples], else: samples)}
    end)
  end
end
