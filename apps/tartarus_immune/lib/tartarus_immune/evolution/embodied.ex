defmodule TartarusImmune.Evolution.Embodied do
  @moduledoc """
  One robot learning a scenario of thesis §7.3.1 on the arena (`TartarusArena.World`),
  with the immune algorithm (Algorithm 5: a repertoire of antibodies, each a 4-5-2
  controller evolved by the (1+1)-online strategy) or, as the baseline of §7.4.1, one
  monolithic controller evolved by the same strategy.

  ## The arena

  2 m x 2 m, the light in the middle (on for S1 and S2; switched for S3), 10 yellow pucks
  scattered at random for S2 and S3, the robot (with a pusher, for the pucks) at a random
  pose. Everything is drawn from the seed.

  ## One iteration (an evaluation period)

  1. sense: the epitope is `TartarusArena.World.normalize/1` of the readings (the two light
     sensors, the ultrasonic, the colour sensor, each 0..1);
  2. immune: `Repertoire.recognize/3` then `Repertoire.select/5` (no external repertoire for
     one robot) pick an antibody; monolithic: the one controller;
  3. its strategy proposes weights (`ES.propose/2`), which drive the wheels (the network's
     two `tanh` outputs are the wheel commands) for up to `period` steps of `dt` seconds
     (after an optional, unscored **recovery period** of `recovery` steps, default 0:
     none, as the thesis describes); the scored period ends early when the sensed epitope leaves
     the antibody's active region after at least `min_period` scored steps (Algorithm 5,
     line 22: "while the current antigen is within the AR of BestAb");
  4. fitness = the scenario's objective (`TartarusImmune.Evolution.Objective`) summed over
     the scored period and divided by its steps (periods cut short compare with full
     ones; `score: :total` leaves the sum undivided, as Eqs. 7.1-7.3 print it); the
     strategy and the antibody's concentration are told;
  5. with `loop: :while_in_region` (Algorithm 5, lines 22-24: "while current Ag space is
     within the AR of BestAb do: Execute and Evolve BestAb"), if the period ran its
     `period` steps with the epitope still in the antibody's region, steps 3-4 are
     repeated for the same antibody in the same iteration (at most `max_inner`
     periods); `loop: :once` (default here; `mix tartarus.evolve` defaults to the
     printed loop) ends the iteration after one evaluation. The monolithic robot
     evaluates once per iteration either way (its region is everything).

  The recovery period comes from the paper of the (1+1)-online strategy the thesis cites
  (Bredeche, Haasdijk and Eiben 2009), not from the thesis, whose loop has none (the
  default, `recovery: 0`): a robot evaluates controllers one after the other without
  being put back, so each new controller starts wherever, and however stuck, the previous
  one left the robot, and its score measures that inheritance as well as itself
  (`TartarusImmune.Evolution.Diagnostics.ordering/1`: driving straight into walls scores
  0.52 per step between other controllers, 0.24 after a recovery period of 20 steps). If
  the recovery already takes the robot out of the selected antibody's active region, the
  antibody's turn is over (line 22) unevaluated and the round starts again from there (at
  most 5 times per iteration); iterations count evaluations. The monolithic baseline gets
  the same recovery. docs/evolution.md gives both settings' results.

  The curve records, per iteration, the antibody used, the fitness and the light.

  ## Test

  After training, `test_episodes` episodes from fresh random poses (and pucks) run the
  learnt controllers without evolving them (immune: the best candidate for the sensed
  epitope, or the nearest antibody when none is within epsilon). With `test_switch:
  :region` (default) the antibody is chosen again as in training: when the epitope has
  left its active region after at least `min_period` steps, or after `period` steps;
  `:period` chooses only every `period` steps. Success (our definitions, as the thesis
  gives none):

    * S1: the robot comes within 0.4 m of the light during a 30 s episode and never bumps
      into a wall (phototaxis with obstacle avoidance: Eq. 7.1 rewards moving fast and
      straight towards the light, not stopping there);
    * S2: at least one puck ends 0.25 m closer to the light than it started (30 s);
    * S3: an episode of 30 s with the light on meets S2's criterion, and one with the light
      off ends with no puck in the gripper and the robot having moved at least 1 m; a
      trial's success is the mean of the two halves.
  """

  alias TartarusArena.World
  alias TartarusTools.Stats
  alias TartarusImmune.Evolution.{ES, NeuralNet, Objective, Repertoire}

  @shape [4, 5, 2]
  # the colour sensor's reading of a yellow puck (thesis §7.3)
  @yellow 3

  @schema [
    scenario: [type: {:in, [:s1, :s2, :s3]}, default: :s1, doc: "S1, S2 or S3"],
    design: [
      type: {:in, [:immune, :monolithic]},
      default: :immune,
      doc: "the immune algorithm or one controller"
    ],
    iterations: [
      type: :pos_integer,
      doc: "evaluation periods (default: 200 for S1, 500 immune / 400 monolithic for S2 and S3)"
    ],
    epsilon: [
      type: :number,
      doc: "cross-reactivity threshold (default 0.45, 0.4, 0.25 for S1, S2, S3)"
    ],
    period: [type: :pos_integer, default: 30, doc: "steps per evaluation period at most"],
    recovery: [
      type: :non_neg_integer,
      default: 0,
      doc: "steps the proposed controller runs unscored before its evaluation period"
    ],
    test_switch: [
      type: {:in, [:region, :period]},
      default: :region,
      doc: "test: re-select when the epitope leaves the antibody's region, or every period"
    ],
    loop: [
      type: {:in, [:once, :while_in_region]},
      default: :once,
      doc:
        "immune: one evaluation per iteration (`:once`), or Algorithm 5's lines 22-24 as printed (`:while_in_region`): evaluate and evolve the selected antibody again while the epitope stays in its active region"
    ],
    max_inner: [
      type: :pos_integer,
      default: 10,
      doc: "`loop: :while_in_region`: evaluation periods per iteration at most"
    ],
    min_period: [
      type: :pos_integer,
      default: 10,
      doc: "steps an evaluation runs before leaving the active region can end it"
    ],
    evaluation: [
      type: {:in, [:region, :fixed]},
      default: :region,
      doc:
        "`:region`: an evaluation period ends when the epitope leaves the antibody's active region (after `min_period` steps); `:fixed`: every period runs its `period` steps (the thesis's \"evaluation period of t' timesteps\"), the region is checked only between periods (training and test)"
    ],
    puck_reward: [
      type: {:in, [:product, :sum]},
      default: :product,
      doc:
        "the reading of Eq. 7.2's f_puck: `b_puck * v_trans` or, as printed, `b_puck + v_trans` (`Objective`)"
    ],
    score: [
      type: {:in, [:per_step, :total]},
      default: :per_step,
      doc:
        "an evaluation's fitness: the objective per step (default) or, as Eqs. 7.1-7.3 print it, summed over the evaluation period"
    ],
    dt: [type: {:range, 1.0e-3, 10}, default: 0.1, doc: "seconds per step"],
    pucks: [type: :non_neg_integer, default: 10, doc: "pucks (S2, S3)"],
    test_episodes: [type: :non_neg_integer, default: 10, doc: "test episodes after training"],
    es: [
      type: :keyword,
      default: [sigma_min: 0.5, p_reeval: 0.2],
      doc: "options of each controller's `TartarusImmune.Evolution.ES` strategy"
    ],
    trace: [type: :boolean, default: false, doc: "keep the robot's trajectory (for plots)"],
    step_budget: [
      type: :pos_integer,
      doc:
        "S1, S2: train until this many scored steps have been driven (instead of `iterations`; the step-matched baseline)"
    ],
    seed: [type: :integer, default: 1, doc: "seed"]
  ]

  @doc "The options of `run/1`."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Trains and tests once. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, result}`: `curve` (`[%{iteration, antibody, fitness, light_on, steps,
  epitope, kind, sigma, puck_steps}]`: per evaluation, the antibody that ran, its fitness,
  the light, the scored steps, the epitope that chose the antibody, what the strategy
  proposed (`:offspring` or `:champion`), the strategy's sigma when it proposed, and the
  scored steps with the colour sensor on yellow),
  `antibodies` (created), `switches` (iterations whose antibody differs from the previous
  one), `test_success` (0..1), `by_light` (S3: the antibodies used with the light on and
  off, and how many were used in both), `reused_after_return` (S3: whether an antibody
  first used in the first light-off phase was used again in the second), `trajectory`
  (poses, with `trace: true`) and `world` (the final world, with `trace: true`),
  `light_switches` (S3), `test_episodes` (each test episode's outcome: success, bumps,
  `final_stall` (the steps at the end of the episode in a row in which the robot's move
  was refused: stuck against a wall, or pushing a puck that cannot move), final distance
  to the light, distance moved, best puck gain towards the light),
  `final_fitness` (mean of the last 20 iterations), `unevaluated_rounds` (rounds whose
  recovery period left the antibody's active region), `repertoire` (the trained
  `TartarusImmune.Evolution.Repertoire`, for `test_repertoire/3`), `evaluations`,
  `training_steps` (scored), `capped_iterations` (iterations stopped by `max_inner`),
  `at_sigma_max` (share of the evaluations that were offspring proposed at the sigma
  ceiling), `loop`, `probes` (`probes/4`). Each curve point also has `inner` (the period's
  number in its iteration), `champion_fitness` (after the evaluation) and
  `forward_steps`; each test episode `reached_light`, `objective` and
  `objective_product` (Eq. 7.x per step, f_puck as printed and as the product),
  `puck_steps`, `puck_ab_steps` and `longest_puck_run` (see `probes/4`).
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "#{inspect(__MODULE__)}.run/1") do
      {:ok, do_run(defaults(Map.new(opts)))}
    end
  end

  @doc """
  The options of `run/1` validated, as a map with the scenario's defaults filled in; raises
  `ArgumentError` for bad options.
  """
  @spec options(keyword()) :: map()
  def options(opts),
    do:
      opts
      |> Tartarus.Options.validate!(@schema, "#{inspect(__MODULE__)}.options/1")
      |> Map.new()
      |> defaults()

  @doc """
  One time step's sample for the objective functions (`TartarusImmune.Evolution.Objective`)
  from a robot's motion and readings. The speeds are those the robot achieved: a robot
  whose move was refused (it drove into a wall, a robot or a stuck puck: `bumped`) did not
  translate, whatever its wheels were told (a real robot's wheel encoders stall).

  `v_trans` is the *forward* translational speed: 0 when the robot backs up. The
  thesis's robot has its one ultrasonic sensor "mounted in front of the robot" and its
  gripper in front; `f_obs = v_trans * (1 - v_rot) * d` pays speed times the free distance
  *ahead*, which measures obstacle avoidance only for a robot moving where its sensor
  looks, and a puck is pushed only forwards. With the absolute speed, driving backwards at
  full speed earned the whole `f_obs` (the free space ahead grows as the robot backs away
  from a wall) while never meeting an obstacle in the sensor or a puck in the gripper, and
  most learnt controllers did just that (docs/evolution.md).

  `b_puck` (`:puck`) is the colour sensor reading yellow (3), as on the thesis's robots:
  "The CS fixed behind the gripper facilitates the detection of the puck based on its
  colour" (§7.3.1, S2), and "For the yellow color, the CS returned a value 3" (§7.3); the
  fitness of embodied evolution is computed on board, from the robot's own sensors. The
  arena's `puck_in_gripper` (a puck anywhere in the pusher's capture zone, up to 34
  degrees off the axis and 1.5 cm from the body) is ground truth the robot cannot sense,
  and counts pucks at the side of the U that the colour sensor does not see.

      iex> alias TartarusArena.World
      iex> w = World.new(seed: 1) |> World.add_robot(:r, x: 1.0, y: 1.0, tool: :pusher)
      iex> r = %{light: {40, 20}, ultrasonic: 100, colour: 3, bumped: false, puck_in_gripper: false}
      iex> TartarusImmune.Evolution.Embodied.sample(w, :r, r).puck
      true
      iex> TartarusImmune.Evolution.Embodied.sample(w, :r, %{r | colour: 7, puck_in_gripper: true}).puck
      false
      iex> TartarusImmune.Evolution.Embodied.sample(World.set_wheels(w, :r, 1.0, 1.0), :r, r).v_trans
      1.0
      iex> TartarusImmune.Evolution.Embodied.sample(World.set_wheels(w, :r, -1.0, -1.0), :r, r).v_trans
      0.0
  """
  @spec sample(World.t(), term(), map()) :: Objective.sample()
  def sample(world, robot, readings) do
    m = World.motion(world, robot)
    {lx, ly} = readings.light

    %{
      v_trans: if(readings.bumped or m.v <= 0, do: 0.0, else: min(m.v_trans, 1.0)),
      v_rot: min(m.v_rot, 1.0),
      d: readings.ultrasonic / 200,
      light: [lx / 100, ly / 100],
      puck: readings.colour == @yellow,
      light_on: World.light_on?(world)
    }
  end

  defp defaults(o) do
    iterations =
      o[:iterations] ||
        case {o.scenario, o.design} do
          {:s1, _} -> 200
          {_, :immune} -> 500
          {_, :monolithic} -> 400
        end

    epsilon =
      cond do
        o.design == :monolithic -> 10.0
        o[:epsilon] -> o.epsilon
        true -> %{s1: 0.45, s2: 0.4, s3: 0.25}[o.scenario]
      end

    Map.merge(o, %{iterations: iterations, epsilon: epsilon})
  end

  @doc """
  The light schedule of S3 for `n` iterations: off, then on from an iteration drawn in
  30-40 % of the run, then off again from one in 60-70 % (each condition lasts well over
  the thesis's minimum of 5 evaluations). Returns the two switch iterations.
  """
  @spec light_switches(pos_integer(), integer()) :: {pos_integer(), pos_integer()}
  def light_switches(n, seed) do
    rng = :rand.seed_s(:exsss, {seed, 3, 3})
    {a, rng} = :rand.uniform_s(rng)
    {b, _} = :rand.uniform_s(rng)
    {round(n * (0.3 + 0.1 * a)), round(n * (0.6 + 0.1 * b))}
  end

  defp do_run(o) do
    rng = :rand.seed_s(:exsss, {o.seed, 7, 1})
    {world, rng} = arena(o, rng, o.scenario != :s3)
    switches = if o.scenario == :s3, do: light_switches(o.iterations, o.seed)

    rep =
      Repertoire.new(epsilon: o.epsilon, shape: @shape, p_sharing: 0.0, origin: :self, es: o.es)

    st = %{world: world, rng: rng, rep: rep, curve: [], traj: [], unevaluated: 0, capped: 0}

    st = train(o, st, switches, 1, 0)

    curve = Enum.reverse(st.curve)
    {success, details, _} = test(o, st.rep, st.rng)
    es = Keyword.merge([sigma_max: 4.0], o.es)

    %{
      scenario: o.scenario,
      design: o.design,
      epsilon: o.epsilon,
      iterations: curve |> Enum.map(& &1.iteration) |> Enum.max(fn -> 0 end),
      curve: curve,
      antibodies: st.rep.next_id - 1,
      unevaluated_rounds: st.unevaluated,
      switches:
        curve
        |> Enum.chunk_every(2, 1, :discard)
        |> Enum.count(fn [a, b] -> a.antibody != b.antibody end),
      test_success: success,
      test_episodes: details,
      light_switches: switches && Tuple.to_list(switches),
      trajectory: Enum.reverse(st.traj),
      world: if(o.trace, do: st.world),
      repertoire: st.rep,
      final_fitness: curve |> Enum.take(-20) |> Enum.map(& &1.fitness) |> Stats.mean() || 0.0,
      loop: o.loop,
      evaluations: length(curve),
      training_steps: curve |> Enum.map(& &1.steps) |> Enum.sum(),
      capped_iterations: st.capped,
      at_sigma_max:
        Enum.count(curve, &(&1.kind == :offspring and &1.sigma >= es[:sigma_max])) /
          max(length(curve), 1),
      probes: probes(st.rep, curve, details, o)
    }
    |> Map.merge(s3_stats(o.scenario, curve, switches))
  end

  # `iterations` iterations, or with `step_budget` until that many scored steps
  defp train(o, st, switches, i, steps) do
    more = if o[:step_budget], do: steps < o.step_budget, else: i <= o.iterations

    if more do
      light = light_at(o.scenario, switches, i)
      st = %{st | world: World.set_light(st.world, if(light, do: :on, else: :off))}
      n = length(st.curve)
      st = iteration(o, st, i, light)
      new = st.curve |> Enum.take(length(st.curve) - n) |> Enum.map(& &1.steps) |> Enum.sum()
      train(o, st, switches, i + 1, steps + new)
    else
      st
    end
  end

  defp s3_stats(:s3, curve, {on_at, off_at}) do
    ids = fn pred -> curve |> Enum.filter(pred) |> Enum.map(& &1.antibody) |> MapSet.new() end
    on = ids.(& &1.light_on)
    off = ids.(&(not &1.light_on))
    first_off = ids.(&(&1.iteration < on_at))
    second_off = ids.(&(&1.iteration >= off_at))

    %{
      by_light: %{
        on: MapSet.size(on),
        off: MapSet.size(off),
        both: MapSet.size(MapSet.intersection(on, off))
      },
      reused_after_return: MapSet.size(MapSet.intersection(first_off, second_off))
    }
  end

  defp s3_stats(_, _, _), do: %{}

  @doc false
  def light_at(:s3, {on_at, off_at}, i), do: i >= on_at and i < off_at
  def light_at(_, _, _), do: true

  @doc false
  # A fresh arena: the robot at a random pose, pucks (S2, S3) at random places.
  def arena(o, rng, light_on) do
    world =
      World.new(
        size: {2.0, 2.0},
        seed: :erlang.phash2({o.seed, :world, rng}),
        light: [on: light_on]
      )

    {x, rng} = between(rng, 0.2, 1.8)
    {y, rng} = between(rng, 0.2, 1.8)
    {th, rng} = between(rng, -:math.pi(), :math.pi())
    world = World.add_robot(world, :robot, x: x, y: y, theta: th, tool: :pusher)
    n = if o.scenario == :s1, do: 0, else: o.pucks

    Enum.reduce(1..n//1, {world, rng}, fn k, {w, rng} ->
      {px, rng} = between(rng, 0.15, 1.85)
      {py, rng} = between(rng, 0.15, 1.85)
      {rx, ry, _} = World.pose(w, :robot)

      if :math.sqrt((px - rx) ** 2 + (py - ry) ** 2) < 0.2 or
           :math.sqrt((px - 1.0) ** 2 + (py - 1.0) ** 2) < 0.15 or not puck_room?(w, px, py),
         do: {w, rng},
         else: {World.add_puck(w, k, x: px, y: py), rng}
    end)
  end

  @doc false
  # Whether a puck (radius 0.03) at (x, y) would not overlap the pucks already placed (a
  # puck drawn onto another is left out, as one drawn too near the robot or the light).
  def puck_room?(world, x, y),
    do:
      Enum.all?(world.pucks, fn {_, p} ->
        (p.x - x) ** 2 + (p.y - y) ** 2 >= (p.radius + 0.03) ** 2
      end)

  defp between(rng, a, b) do
    {u, rng} = :rand.uniform_s(rng)
    {a + (b - a) * u, rng}
  end

  # One iteration: one evaluation. A round of Algorithm 5 whose recovery period already
  # takes the robot out of the selected antibody's active region ends there, unevaluated
  # (line 22: the antibody's turn is over), and the next round starts from where the robot
  # is; after @max_aborted such rounds the evaluation goes ahead regardless.
  @max_aborted 5

  defp iteration(o, st, i, light, aborted \\ 0) do
    {readings, world} = World.sense(st.world, :robot)
    ep = World.normalize(readings)
    {rep, cands, rng} = Repertoire.recognize(st.rep, ep, st.rng)
    {rep, key, _, rng} = Repertoire.select(rep, cands, ep, %{}, rng)
    evaluate(o, %{st | world: world, rep: rep, rng: rng}, i, light, aborted, key, ep, readings, 1)
  end

  # Lines 22-24 of Algorithm 5: "while current Ag space is within the AR of BestAb do:
  # Execute and Evolve BestAb". One evaluation period of the antibody `key`; with `loop:
  # :while_in_region` (immune only) another follows, in the same iteration, while the
  # period ran to its end with the epitope still in the active region (at most
  # `max_inner` periods).
  defp evaluate(o, st, i, light, aborted, key, ep, readings, inner) do
    %{world: world, rep: rep, rng: rng} = st
    ab = rep.antibodies[key]
    {kind, w, rng} = ES.propose(ab.es, rng)
    {world, readings, traj} = recover(o, world, w, readings, o.recovery, st.traj)

    if aborted < @max_aborted and o.recovery > 0 and
         Repertoire.affinity(World.normalize(readings), ab.paratope) > o.epsilon do
      st = %{st | world: world, rep: rep, rng: rng, traj: traj, unevaluated: st.unevaluated + 1}
      # a later period of the same iteration: the antibody's turn is over
      if inner > 1, do: st, else: iteration(o, st, i, light, aborted + 1)
    else
      {world, samples, traj, next} =
        execute(o, world, w, ab.paratope, readings, o.period, [], traj)

      fitness = score(o, samples)
      es = ES.tell(ab.es, {kind, w}, fitness)
      rep = Repertoire.put_es(rep, key, es)
      rep = Repertoire.report(rep, key, fitness)
      inside = Repertoire.affinity(World.normalize(next), ab.paratope) <= o.epsilon

      point = %{
        iteration: i,
        inner: inner,
        antibody: elem(key, 1),
        fitness: fitness,
        champion_fitness: es.fitness,
        light_on: light,
        steps: length(samples),
        epitope: ep,
        kind: kind,
        sigma: ab.es.sigma,
        puck_steps: Enum.count(samples, & &1.puck),
        forward_steps: Enum.count(samples, &(&1.v_trans > 0))
      }

      st = %{st | world: world, rep: rep, rng: rng, curve: [point | st.curve], traj: traj}

      again =
        o.loop == :while_in_region and o.design == :immune and inside and
          Map.has_key?(rep.antibodies, key)

      cond do
        again and inner < o.max_inner ->
          evaluate(o, st, i, light, 0, key, World.normalize(next), next, inner + 1)

        again ->
          %{st | capped: st.capped + 1}

        true ->
          st
      end
    end
  end

  # An evaluation's fitness: the objective per step, or summed over the period (Eq. 7.1's
  # sum from t = 0 to t').
  defp score(o, samples) do
    total = Objective.fitness(o.scenario, samples, puck_reward: o.puck_reward)
    if o.score == :total, do: total, else: total / max(length(samples), 1)
  end

  # The recovery period: `w` drives for `n` steps, unscored.
  defp recover(_o, world, _w, readings, 0, traj), do: {world, readings, traj}

  defp recover(o, world, w, readings, n, traj) do
    [l, r] = NeuralNet.forward(@shape, w, World.normalize(readings))
    world = World.step(world, %{robot: {l, r}}, o.dt)
    {next, world} = World.sense(world, :robot)
    traj = if o.trace, do: [World.pose(world, :robot) | traj], else: traj
    recover(o, world, w, next, n - 1, traj)
  end

  # Runs weights `w` for up to `n` steps; stops when the epitope leaves `paratope`'s
  # active region (after at least `min_period` steps). Returns the last readings too.
  defp execute(o, world, w, paratope, readings, n, samples, traj) do
    [l, r] = NeuralNet.forward(@shape, w, World.normalize(readings))
    world = World.step(world, %{robot: {l, r}}, o.dt)
    {next, world} = World.sense(world, :robot)
    sample = sample(world, :robot, next)

    traj = if o.trace, do: [World.pose(world, :robot) | traj], else: traj
    samples = [sample | samples]

    done =
      o.evaluation == :region and length(samples) >= o.min_period and
        Repertoire.affinity(World.normalize(next), paratope) > o.epsilon

    if n <= 1 or done,
      do: {world, samples, traj, next},
      else: execute(o, world, w, paratope, next, n - 1, samples, traj)
  end

  # -- test -----------------------------------------------------------------------

  defp test(o, rep, rng), do: test_repertoire(o, rep, rng)

  @doc """
  Tests a trained repertoire (the test of the module doc) with `o`, the options of `run/1`
  as a map with defaults filled in (`options/1`). Returns `{success, episodes, rng}`.

  Instead of a repertoire, `rep` may be a fixed controller: a function from the normalized
  epitope to the two wheel commands `[left, right]` (hand-made controllers measure what
  the test asks, `TartarusImmune.Evolution.Diagnostics`).
  """
  @spec test_repertoire(map(), Repertoire.t() | ([float()] -> [float()]), :rand.state()) ::
          {float() | nil, [map()], :rand.state()}
  def test_repertoire(%{test_episodes: 0}, _rep, rng), do: {nil, [], rng}

  def test_repertoire(o, rep, rng) do
    {episodes, rng} =
      Enum.map_reduce(1..o.test_episodes, rng, fn k, rng ->
        case o.scenario do
          :s3 ->
            {a, rng} = episode(o, rep, rng, true, k)
            {b, rng} = episode(o, rep, rng, false, k)
            {[a, b], rng}

          _ ->
            {a, rng} = episode(o, rep, rng, true, k)
            {[a], rng}
        end
      end)

    episodes = List.flatten(episodes)
    {Float.round(Stats.mean(Enum.map(episodes, & &1.success)) || 0.0, 3), episodes, rng}
  end

  @episode_steps 300
  # the behaviour probe's obstacle: nearer than 20 cm (of the ultrasonic's 200)
  @near 0.1

  defp episode(o, rep, rng, light, _k) do
    {world, rng} = arena(o, rng, light)
    pucks0 = world.pucks
    {x0, y0, _} = World.pose(world, :robot)
    {world, {bumps, stall}, near, acc} = drive(o, rep, world, @episode_steps, {0, 0}, [])
    {x1, y1, _} = World.pose(world, :robot)
    {readings, _} = World.sense(world, :robot)

    ok =
      case {o.scenario, light} do
        {:s1, _} ->
          bumps == 0 and Enum.any?(near)

        {_, true} ->
          Enum.any?(world.pucks, fn {id, p} ->
            p0 = pucks0[id]
            dist(p0.x, p0.y, 1.0, 1.0) - dist(p.x, p.y, 1.0, 1.0) >= 0.25
          end)

        {:s3, false} ->
          not readings.puck_in_gripper and dist(x0, y0, x1, y1) >= 1.0
      end

    detail = %{
      light_on: light,
      success: if(ok, do: 1.0, else: 0.0),
      bumps: bumps,
      final_stall: stall,
      final_light_distance: Float.round(dist(x1, y1, 1.0, 1.0), 3),
      moved: Float.round(dist(x0, y0, x1, y1), 3),
      best_puck_gain:
        world.pucks
        |> Enum.map(fn {id, p} ->
          dist(pucks0[id].x, pucks0[id].y, 1.0, 1.0) - dist(p.x, p.y, 1.0, 1.0)
        end)
        |> Enum.max(fn -> 0.0 end)
        |> Float.round(3),
      reached_light: Enum.any?(near),
      objective: Float.round(acc.sum / max(acc.n, 1), 4),
      objective_product: Float.round(acc.product / max(acc.n, 1), 4),
      puck_steps: acc.puck,
      puck_ab_steps: acc.puck_ab,
      longest_puck_run: max(acc.best_run, acc.run),
      puck_near_by_antibody: acc.near,
      puck_far_by_antibody: acc.far
    }

    {detail, rng}
  end

  # The learnt controllers, frozen. `test_switch: :period`: the controller is chosen again
  # every `period` steps; `:region`: as in training, also when the epitope has left the
  # chosen antibody's active region after at least `min_period` steps (Algorithm 5, line 22).
  #
  # `acc` counts, for the probes, over the steps: the objective Eq. 7.1-7.3 per step under
  # the printed f_puck (`sum`) and the product (from the readings sensed after each step,
  # as in training: the episode's first 299 steps), the steps whose controller was applied
  # with the colour sensor on yellow (`puck`) and of those the steps run by a puck antibody
  # (`puck_ab`), and runs of steps with a puck seen while moving forwards.
  defp drive(o, rep, world, left, bumps, near) do
    acc = %{
      n: 0,
      sum: 0.0,
      product: 0.0,
      puck: 0,
      puck_ab: 0,
      run: 0,
      best_run: 0,
      near: %{},
      far: %{}
    }

    drive(o, rep, world, left, bumps, near, nil, 0, acc)
  end

  defp drive(_o, _rep, world, 0, bumps, near, _cur, _k, acc), do: {world, bumps, near, acc}

  defp drive(o, rep, world, left, bumps, near, cur, k, acc) do
    {r, world} = World.sense(world, :robot)
    ep = World.normalize(r)
    acc = if left < @episode_steps, do: account(o, acc, sample(world, :robot, r)), else: acc

    {cur, k, ep, world} =
      cond do
        is_function(rep, 1) ->
          {rep, k, ep, world}

        # `evaluation: :fixed`: the region is checked between periods only, and the
        # antibody runs on while the epitope is in it (as in training)
        o.evaluation == :fixed and cur != nil and k >= o.period and
            Repertoire.affinity(ep, cur.paratope) <= o.epsilon ->
          {cur, 0, ep, world}

        cur == nil or k >= o.period ->
          # (the reading that chose is not the one the controller then acts on)
          {r, world} = World.sense(world, :robot)
          {frozen(rep, ep), 0, World.normalize(r), world}

        o.evaluation == :region and o.test_switch == :region and k >= o.min_period and
            Repertoire.affinity(ep, cur.paratope) > o.epsilon ->
          {frozen(rep, ep), 0, ep, world}

        true ->
          {cur, k, ep, world}
      end

    acc =
      if puck_antibody?(ep),
        do: %{
          acc
          | puck: acc.puck + 1,
            puck_ab:
              acc.puck_ab + if(is_map(cur) and puck_antibody?(cur.paratope), do: 1, else: 0)
        },
        else: acc

    acc = if puck_antibody?(ep) and is_map(cur), do: chosen(acc, ep, cur.id), else: acc

    [l, rr] =
      if is_function(cur, 1), do: cur.(ep), else: NeuralNet.forward(@shape, cur.es.champion, ep)

    world = World.step(world, %{robot: {l, rr}}, o.dt)
    {x, y, _} = World.pose(world, :robot)
    bumped = world.robots[:robot].bumped

    drive(
      o,
      rep,
      world,
      left - 1,
      if(bumped, do: {elem(bumps, 0) + 1, elem(bumps, 1) + 1}, else: {elem(bumps, 0), 0}),
      [dist(x, y, 1.0, 1.0) <= 0.4 | near],
      cur,
      k + 1,
      acc
    )
  end

  # the behaviour probe: which antibody runs while a puck is held, with an obstacle
  # nearer than 20 cm (`near`) or not (`far`)
  defp chosen(acc, ep, id) do
    side = if Enum.at(ep, 2) < @near, do: :near, else: :far
    Map.update!(acc, side, &Map.update(&1, id, 1, fn n -> n + 1 end))
  end

  defp account(o, acc, sample) do
    run = if sample.puck and sample.v_trans > 0, do: acc.run + 1, else: 0

    %{
      acc
      | n: acc.n + 1,
        sum: acc.sum + Objective.step(o.scenario, sample, :sum),
        product: acc.product + Objective.step(o.scenario, sample, :product),
        run: run,
        best_run: max(acc.best_run, run)
    }
  end

  # -- probes (docs/evolution.md, the pre-registration of 2026-11-27) ------------------

  # the ultrasonic reading (normalized) below which a puck antibody is a
  # puck-with-obstacle antibody: 40 cm of 200
  @obstacle 0.2
  # consecutive steps with a puck seen while moving forwards that count as keeping a puck
  @kept_run 20

  @doc """
  What the training periods were (the trace behind the probes): `stalled_share` (periods
  in which the robot moved forwards in fewer than half of the steps), `full_share`
  (periods that ran their 30 steps), the mean fitness of stalled and of moving periods
  (`fitness_stalled`, `fitness_moving`), and of the final repertoire's champions how many
  were set by a stalled period (`champions_stalled` of `champions`; the champion's period
  is the last evaluation of the antibody whose fitness is the champion's), and the same
  for the antibodies of a wall ahead (paratope's ultrasonic below 0.2: `wall_champions`,
  `wall_champions_stalled`, `wall_champion_steps`, the mean length of their periods).
  """
  @spec trace(Repertoire.t(), [map()]) :: map()
  def trace(rep, curve) do
    stalled? = &(&1.forward_steps * 2 < &1.steps)
    {st, mv} = Enum.split_with(curve, stalled?)
    mean = fn pts -> pts |> Enum.map(& &1.fitness) |> Stats.mean() end

    champs =
      for ab <- Map.values(rep.antibodies),
          pt =
            curve
            |> Enum.filter(&(&1.antibody == ab.id and &1.fitness == ab.es.fitness))
            |> List.last(),
          pt != nil,
          do: {ab, pt}

    wall = Enum.filter(champs, fn {ab, _} -> Enum.at(ab.paratope, 2) < @obstacle end)
    champs = Enum.map(champs, &elem(&1, 1))
    n = max(length(curve), 1)

    %{
      stalled_share: length(st) / n,
      full_share: Enum.count(curve, &(&1.steps >= 30)) / n,
      fitness_stalled: mean.(st),
      fitness_moving: mean.(mv),
      champions: length(champs),
      champions_stalled: Enum.count(champs, stalled?),
      wall_champions: length(wall),
      wall_champions_stalled: Enum.count(wall, fn {_, pt} -> stalled?.(pt) end),
      wall_champion_steps: wall |> Enum.map(fn {_, pt} -> pt.steps end) |> Stats.mean()
    }
  end

  @doc """
  Whether a paratope (or an epitope) has the colour sensor on yellow (3 of 0..9): a
  **puck antibody** (probe (a) of docs/evolution.md).

      iex> TartarusImmune.Evolution.Embodied.puck_antibody?([0.5, 0.5, 0.9, 3 / 9])
      true
      iex> TartarusImmune.Evolution.Embodied.puck_antibody?([0.5, 0.5, 0.9, 7 / 9])
      false
  """
  @spec puck_antibody?([number()]) :: boolean()
  def puck_antibody?(paratope), do: round(Enum.at(paratope, 3) * 9) == @yellow

  @doc """
  Whether a paratope is a **puck-with-obstacle antibody**: a puck antibody whose
  ultrasonic component is below 0.2 (40 cm).

      iex> TartarusImmune.Evolution.Embodied.puck_obstacle_antibody?([0.5, 0.5, 0.1, 3 / 9])
      true
      iex> TartarusImmune.Evolution.Embodied.puck_obstacle_antibody?([0.5, 0.5, 0.3, 3 / 9])
      false
  """
  @spec puck_obstacle_antibody?([number()]) :: boolean()
  def puck_obstacle_antibody?(paratope),
    do: puck_antibody?(paratope) and Enum.at(paratope, 2) < @obstacle

  @doc """
  The probes of a trained run (the pre-registration in docs/evolution.md), from the
  final repertoire `rep`, the training `curve` and the test `episodes` (the light-on ones
  count):

    * structure: `puck_antibodies`, `puck_obstacle_antibodies`, `holds_puck_and_obstacle`,
      `puck_ultrasonic` (the puck antibodies' ultrasonic components, ascending);
    * evaluations: `evaluations_by_antibody` (id => evaluations in training),
      `puck_antibody_evaluations` (those of the final repertoire's puck antibodies);
    * use: `puck_steps` (test steps whose controller was applied with the colour sensor
      on yellow), `puck_ab_steps` (of those, run by a puck antibody), `puck_use` (their
      ratio, nil without such steps);
    * learning: `test_objective` (the objective per step, f_puck as printed, mean over
      the episodes), `test_objective_product`, `puck_champion_gain` (mean over the puck
      antibodies of their champion's fitness at the end minus after their first
      evaluation; nil without one), `puck_champion_improved` (gain above 0);
    * behaviours: `wall_free_episodes` (no refused move), `light_episodes` (within 0.4 m
      of the light), `puck_kept_episodes` (20 steps in a row with a puck seen while moving
      forwards), out of `episodes`; `fails_a_behaviour` (one of the three in fewer than
      half of the episodes);
    * the puck-with-obstacle antibody **by behaviour** (issue 46): over the test steps
      whose controller was applied with a puck held (colour sensor on yellow),
      `puck_near_steps` with an obstacle nearer than 20 cm (ultrasonic below 0.1) and
      `puck_far_steps` without; `puck_near_antibody` and `puck_far_antibody`, the
      antibody that ran most of each (ties: the lower id); `holds_puck_obstacle_by_behaviour`
      when there are near steps and their antibody is not the far steps' one;
      `puck_near_antibody_share`, the share of the near steps it ran.
  """
  @spec probes(Repertoire.t(), [map()], [map()], map()) :: map()
  def probes(rep, curve, episodes, _o) do
    abs = Map.values(rep.antibodies)
    puck = Enum.filter(abs, &puck_antibody?(&1.paratope))
    by_ab = Enum.group_by(curve, & &1.antibody)
    evals = Map.new(by_ab, fn {id, pts} -> {id, length(pts)} end)

    gains =
      for ab <- puck, pts = by_ab[ab.id], pts != nil, ab.es.fitness != nil do
        ab.es.fitness - hd(pts).champion_fitness
      end

    on = Enum.filter(episodes, & &1.light_on)
    count = fn pred -> Enum.count(on, pred) end
    half = length(on) / 2
    puck_steps = on |> Enum.map(& &1.puck_steps) |> Enum.sum()
    puck_ab_steps = on |> Enum.map(& &1.puck_ab_steps) |> Enum.sum()
    gain = Stats.mean(gains)

    behaviours = %{
      wall_free_episodes: count.(&(&1.bumps == 0)),
      light_episodes: count.(& &1.reached_light),
      puck_kept_episodes: count.(&(&1.longest_puck_run >= @kept_run))
    }

    near = on |> Enum.map(&Map.get(&1, :puck_near_by_antibody, %{})) |> sum_counts()
    far = on |> Enum.map(&Map.get(&1, :puck_far_by_antibody, %{})) |> sum_counts()
    near_ab = mode(near)
    far_ab = mode(far)
    near_steps = near |> Map.values() |> Enum.sum()

    Map.merge(behaviours, %{
      puck_near_steps: near_steps,
      puck_far_steps: far |> Map.values() |> Enum.sum(),
      puck_near_antibody: near_ab,
      puck_far_antibody: far_ab,
      puck_near_antibody_share: if(near_ab, do: near[near_ab] / near_steps),
      holds_puck_obstacle_by_behaviour: near_ab != nil and near_ab != far_ab,
      trace: trace(rep, curve),
      episodes: length(on),
      fails_a_behaviour: on != [] and Enum.any?(Map.values(behaviours), &(&1 < half)),
      puck_antibodies: length(puck),
      puck_obstacle_antibodies: Enum.count(puck, &puck_obstacle_antibody?(&1.paratope)),
      puck_ultrasonic: puck |> Enum.map(&Float.round(Enum.at(&1.paratope, 2), 3)) |> Enum.sort(),
      holds_puck_and_obstacle:
        puck != [] and Enum.any?(puck, &puck_obstacle_antibody?(&1.paratope)),
      evaluations_by_antibody: Map.new(evals, fn {id, n} -> {to_string(id), n} end),
      puck_antibody_evaluations: puck |> Enum.map(&Map.get(evals, &1.id, 0)) |> Enum.sum(),
      puck_steps: puck_steps,
      puck_ab_steps: puck_ab_steps,
      puck_use: if(puck_steps > 0, do: puck_ab_steps / puck_steps),
      test_objective: Stats.mean(Enum.map(on, & &1.objective)),
      test_objective_product: Stats.mean(Enum.map(on, & &1.objective_product)),
      puck_champion_gain: gain,
      puck_champion_improved: gain != nil and gain > 0
    })
  end

  defp sum_counts(maps), do: Enum.reduce(maps, %{}, &Map.merge(&2, &1, fn _, a, b -> a + b end))

  # the antibody counted most (the lower id on a tie), nil for none
  defp mode(counts) when counts == %{}, do: nil
  defp mode(counts), do: counts |> Enum.min_by(fn {id, n} -> {-n, id} end) |> elem(0)

  defp frozen(rep, ep) do
    case Repertoire.candidates(rep, ep) do
      [] ->
        rep.antibodies
        |> Enum.min_by(fn {k, ab} -> {Repertoire.affinity(ep, ab.paratope), k} end)
        |> elem(1)

      cands ->
        rep.antibodies[
          Enum.max_by(cands, fn {k, _} -> rep.antibodies[k].concentration end) |> elem(0)
        ]
    end
  end

  defp dist(x0, y0, x1, y1), do: :math.sqrt((x1 - x0) ** 2 + (y1 - y0) ** 2)
end
