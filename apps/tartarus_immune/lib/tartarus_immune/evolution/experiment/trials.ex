defmodule TartarusImmune.Evolution.Experiment.Trials do
  @moduledoc """
  `s1`, `s2`, `s3` and `monolithic` of `mix tartarus.evolve` (thesis §7.3.1, §7.4.1,
  Figs. 7.3-7.5): `trials` runs of one robot learning a scenario with the immune
  algorithm and, beside each, the monolithic baseline on the same seed
  (`TartarusImmune.Evolution.Embodied`); `monolithic` runs the baseline alone on all
  three scenarios. A sweep (`TartarusEmu.Sweep`): an arm is `<scenario>_<design>`, the
  seeds are `seed + trial`; the first trial keeps its trace (fitness curves and the
  robot's path). The summary tests "immune better than monolithic" on test success and
  on the objective per step in the test (`test_objective`) with exact one-sided
  Mann-Whitney U tests, and gives per arm the probes of docs/evolution.md
  (pre-registration of 2026-11-27: structure, use, behaviours, evaluations per antibody,
  the trace of the champions' periods) and `done_means`, the pre-registered criteria;
  with `matched`, the arm `<scenario>_monolithic_matched` is the baseline trained for as
  many scored steps as the immune robot drove on the same seed. Run it with
  `TartarusImmune.Evolution.Experiment.run/1`.
  """

  import TartarusImmune.Evolution.Experiment.Shared, only: [mean2: 1]

  alias TartarusImmune.Evolution.Embodied
  alias TartarusTools.{Series, Stats, SVG}

  @doc "The sweep (arms, seeds, run, metrics, tests, rows of `runs.csv`) for options `p`."
  @spec spec(map()) :: map()
  def spec(p) do
    exp = p.experiment
    sc = scenario(exp)
    scenarios = if exp == :monolithic, do: [:s1, :s2, :s3], else: [sc]
    designs = if exp == :monolithic, do: [:monolithic], else: [:immune, :monolithic]

    arms =
      for sc <- scenarios,
          d <- designs,
          do: {"#{sc}_#{d}", %{scenario: sc, design: d, evaluation: :region}}

    arms =
      if matched?(p),
        do:
          arms ++
            [
              {"#{sc}_monolithic_matched",
               %{scenario: sc, design: :monolithic, matched: true, evaluation: :region}}
            ],
        else: arms

    # `s2_fixed` (issue 46): the fixed evaluation period t' as a labelled arm, with its
    # own step-matched baseline
    arms =
      if exp == :s2_fixed,
        do:
          arms ++
            [
              {"s2_immune_fixed", %{scenario: :s2, design: :immune, evaluation: :fixed}},
              {"s2_monolithic_matched_fixed",
               %{scenario: :s2, design: :monolithic, matched: true, evaluation: :fixed}}
            ],
        else: arms

    exact = [method: :exact]

    matched_tests =
      if matched?(p),
        do: [{"#{sc}_immune", :greater, "#{sc}_monolithic_matched", :test_objective, exact}],
        else: []

    fixed_tests =
      if exp == :s2_fixed,
        do: [
          {"s2_immune_fixed", :greater, "s2_monolithic_matched_fixed", :test_objective, exact},
          {"s2_immune_fixed", :greater, "s2_immune", :test_objective, exact},
          {"s2_immune_fixed", :greater, "s2_monolithic", :test_objective, exact}
        ],
        else: []

    tests =
      if exp == :monolithic,
        do: [],
        else: [
          {"#{sc}_immune", :greater, "#{sc}_monolithic", :test_success, exact},
          {"#{sc}_immune", :greater, "#{sc}_monolithic", :test_objective, exact}
        ]

    %{
      arms: arms,
      seeds: Enum.map(0..(p.trials - 1), &(p.seed + &1)),
      run: fn arm, seed -> run_one(arm.opts, seed, p) end,
      metrics: [
        test_success: :test_success,
        test_objective: &(&1.probes.test_objective || 0.0),
        evaluations: :evaluations,
        puck_antibody_evaluations: & &1.probes.puck_antibody_evaluations,
        antibodies: :antibodies,
        switches: :switches
      ],
      tests: tests ++ matched_tests ++ fixed_tests,
      csv:
        {~w(scenario design trial antibodies switches final_fitness test_success),
         fn run ->
           r = run.summary

           [
             [
               r.scenario,
               r.design,
               r.trial,
               r.antibodies,
               r.switches,
               Float.round(r.final_fitness, 4),
               r.test_success
             ]
           ]
         end}
    }
  end

  defp run_one(%{scenario: sc, design: d} = arm, seed, p) do
    trial = seed - p.seed
    ev = [evaluation: arm.evaluation]

    # the step-matched baseline: as many scored steps as the immune robot drove (its
    # training is run again; the same seed gives the same run)
    budget =
      if arm[:matched] do
        {:ok, imm} = Embodied.run(common(sc, :immune, seed, p) ++ ev ++ [test_episodes: 0])
        [step_budget: imm.training_steps]
      else
        []
      end

    {:ok, r} = Embodied.run(common(sc, d, seed, p) ++ ev ++ [trace: trial == 0] ++ budget)

    Map.merge(r, %{
      trial: trial,
      seed: seed,
      matched: arm[:matched] == true,
      evaluation: arm.evaluation
    })
  end

  # the scenario an experiment runs (`s2_fixed` is S2's)
  defp scenario(:s2_fixed), do: :s2
  defp scenario(exp), do: exp

  # whether the step-matched baseline is an arm (the default for S1 and S2)
  defp matched?(p), do: p.experiment == :s2_fixed or (p[:matched] and p.experiment in [:s1, :s2])

  defp common(sc, d, seed, p) do
    [
      scenario: sc,
      design: d,
      seed: seed,
      recovery: p.recovery,
      period: p.period,
      min_period: p.min_period,
      loop: p.loop,
      max_inner: p.max_inner,
      es: [sigma_min: 0.5, p_reeval: 0.2, sigma_max: p.sigma_max * 1.0],
      puck_reward: p.puck_reward,
      score: p.score
    ]
  end

  # a run's design, `monolithic_matched` for the step-matched baseline, `_fixed` with the
  # fixed evaluation period
  defp name(r) do
    base = if r.matched, do: "monolithic_matched", else: to_string(r.design)
    if r.evaluation == :fixed, do: base <> "_fixed", else: base
  end

  @doc "Points of the series: the trials."
  @spec points(map()) :: pos_integer()
  def points(p), do: p.trials

  @doc "Test success per trial, one series per arm."
  @spec series([map()], map()) :: Series.t()
  def series(runs, _p) do
    Enum.reduce(runs, Series.new(), fn r, series ->
      Series.record(
        series,
        :"test_success_#{r.scenario}_#{name(r)}",
        r.trial + 1,
        r.test_success
      )
    end)
  end

  @doc "The fitness curves and paths of the first trial (`runs.csv` is the sweep's)."
  @spec write(Path.t(), [map()], map()) :: [Path.t()]
  def write(dir, runs, p) do
    curves =
      for r <- runs, r.trial == 0 do
        file = Path.join(dir, "curve_#{r.scenario}_#{name(r)}.svg")

        series =
          r.curve
          |> Enum.group_by(& &1.antibody)
          |> Enum.sort()
          |> Enum.map(fn {id, pts} ->
            %{name: "Ab#{id}", points: Enum.map(pts, &{&1.iteration, Float.round(&1.fitness, 4)})}
          end)

        light =
          case r.light_switches do
            [on, off] -> "; light on at #{on}, off at #{off}"
            _ -> ""
          end

        File.write!(
          file,
          SVG.line_chart(series,
            lines: false,
            title:
              "#{String.upcase(to_string(r.scenario))} #{name(r)}, seed #{r.seed}: fitness by antibody (#{r.evaluations} evaluations, #{r.switches} switches#{light})",
            x_label: "iteration",
            y_label:
              if(p.score == :total,
                do: "fitness (summed over the period)",
                else: "fitness per step"
              )
          )
        )

        traj = Path.join(dir, "trajectory_#{r.scenario}_#{name(r)}.svg")

        points =
          r.trajectory |> Enum.with_index() |> Enum.map(fn {{x, y, _}, i} -> {i * 0.1, x, y} end)

        File.write!(
          traj,
          TartarusArena.Render.trajectories(r.world, %{"robot" => points},
            title:
              "#{String.upcase(to_string(r.scenario))}, #{r.design}: the robot's path while learning",
            subtitle: "#{r.scenario}, #{r.design}, the first trial: seed #{p.seed}"
          )
        )

        [file, traj]
      end

    List.flatten(curves) ++ figure(dir, runs, p)
  end

  @fixed_arms ~w(immune monolithic_matched immune_fixed monolithic_matched_fixed monolithic)

  # `s2_fixed`: Eq. 7.2 per step in the test, per arm (docs/evolution/s2_fixed.svg)
  defp figure(dir, runs, %{experiment: :s2_fixed} = p) do
    groups =
      for d <- @fixed_arms do
        rs = Enum.filter(runs, &(name(&1) == d))
        steps = rs |> Enum.map(& &1.training_steps) |> Stats.mean()
        label = "#{d} (#{if steps, do: round(steps), else: 0} steps)"
        {label, Enum.map(rs, &(&1.probes.test_objective || 0.0))}
      end

    file = Path.join(dir, "s2_fixed.svg")

    File.write!(
      file,
      SVG.box_plot(groups,
        title:
          "S2: region-ended against fixed evaluation periods (t' = #{p.period} steps), seeds #{p.seed}-#{p.seed + p.trials - 1}",
        y_label: "Eq. 7.2 per step in the test (printed f_puck)"
      )
    )

    [file]
  end

  defp figure(_dir, _runs, _p), do: []

  @doc "The summary: per arm, and the test of immune against monolithic."
  @spec summary([map()], map()) :: map()
  def summary(runs, p) do
    exp = scenario(p.experiment)
    arm = fn sc, d -> Enum.filter(runs, &(&1.scenario == sc and name(&1) == "#{d}")) end
    key = fn sc, d -> "#{sc}_#{d}" end

    arms =
      for sc <- [:s1, :s2, :s3],
          d <- [
            :immune,
            :monolithic,
            :monolithic_matched,
            :immune_fixed,
            :monolithic_matched_fixed
          ],
          (runs = arm.(sc, d)) != [],
          into: %{} do
        s3 =
          if sc == :s3,
            do: %{
              antibodies_light_on: mean2(for r <- runs, do: r.by_light.on),
              antibodies_light_off: mean2(for r <- runs, do: r.by_light.off),
              antibodies_used_in_both: mean2(for r <- runs, do: r.by_light.both),
              trials_reusing_after_return: Enum.count(runs, &(&1.reused_after_return > 0))
            },
            else: %{}

        {key.(sc, d),
         Map.merge(
           %{
             test_success: mean2(Enum.map(runs, & &1.test_success)),
             test_success_by_trial: Enum.map(runs, & &1.test_success),
             antibodies: mean2(Enum.map(runs, & &1.antibodies)),
             switches: mean2(Enum.map(runs, & &1.switches)),
             final_fitness: mean2(Enum.map(runs, & &1.final_fitness)),
             iterations: hd(runs).iterations,
             epsilon: hd(runs).epsilon
           },
           Map.merge(s3, probes(runs))
         )}
      end

    main = if exp == :monolithic, do: nil, else: arms[key.(exp, :immune)]
    mono = if exp == :monolithic, do: nil, else: arms[key.(exp, :monolithic)]

    test =
      main && mono &&
        Stats.mann_whitney(main.test_success_by_trial, mono.test_success_by_trial, method: :exact)

    obj =
      main && mono &&
        Stats.mann_whitney(main.test_objective_by_trial, mono.test_objective_by_trial,
          method: :exact
        )

    matched = arms[key.(exp, :monolithic_matched)]

    obj_matched =
      main && matched &&
        Stats.mann_whitney(main.test_objective_by_trial, matched.test_objective_by_trial,
          method: :exact
        )

    %{
      experiment: to_string(p.experiment),
      trials: p.trials,
      comparison: if(matched, do: "step_matched", else: "iterations"),
      matched_objective_p_value: obj_matched && Float.round(obj_matched.p_value, 6),
      seeds: [p.seed, p.seed + p.trials - 1],
      loop: to_string(p.loop),
      max_inner: p.max_inner,
      sigma_max: p.sigma_max,
      objective_mann_whitney_u: obj && obj.u,
      objective_p_value: obj && Float.round(obj.p_value, 6),
      done_means:
        Map.merge(
          done_means(main, mono, obj, arms),
          if(p.experiment == :s2_fixed, do: %{fixed_period: fixed_period(arms)}, else: %{})
        ),
      arms: arms,
      antibodies: main && main.antibodies,
      test_success:
        if(main, do: main.test_success, else: Map.new(arms, fn {k, v} -> {k, v.test_success} end)),
      test_success_monolithic: mono && mono.test_success,
      recovery: p.recovery,
      puck_reward: to_string(p.puck_reward),
      period: p.period,
      min_period: p.min_period,
      score: to_string(p.score),
      mann_whitney_u: test && test.u,
      p_value: test && Float.round(test.p_value, 4),
      immune_beats_monolithic: if(test, do: test.p_value < 0.05)
    }
  end

  # the per-arm figures of the probes (docs/evolution.md, pre-registration of 2026-11-27)
  defp probes(runs) do
    pr = Enum.map(runs, & &1.probes)
    n = length(runs)
    share = fn k -> Float.round(k / n, 3) end
    steps = pr |> Enum.map(& &1.puck_steps) |> Enum.sum()
    ab_steps = pr |> Enum.map(& &1.puck_ab_steps) |> Enum.sum()
    first10 = Enum.filter(runs, &(&1.trial < 10))

    %{
      evaluations: mean2(Enum.map(runs, & &1.evaluations)),
      evaluations_by_trial: Enum.map(runs, & &1.evaluations),
      training_steps: mean2(Enum.map(runs, & &1.training_steps)),
      capped_iterations: mean2(Enum.map(runs, & &1.capped_iterations)),
      at_sigma_max: mean2(Enum.map(runs, & &1.at_sigma_max)),
      evaluations_per_antibody:
        mean2(
          Enum.map(runs, &(&1.evaluations / max(map_size(&1.probes.evaluations_by_antibody), 1)))
        ),
      evaluations_by_antibody_by_trial: Enum.map(pr, & &1.evaluations_by_antibody),
      puck_antibodies: mean2(Enum.map(pr, & &1.puck_antibodies)),
      puck_antibody_evaluations: mean2(Enum.map(pr, & &1.puck_antibody_evaluations)),
      puck_antibody_evaluations_by_trial: Enum.map(pr, & &1.puck_antibody_evaluations),
      trials_with_puck_antibody: Enum.count(pr, &(&1.puck_antibodies > 0)),
      trials_with_puck_and_obstacle: Enum.count(pr, & &1.holds_puck_and_obstacle),
      trials_puck_obstacle_by_behaviour: Enum.count(pr, & &1.holds_puck_obstacle_by_behaviour),
      share_puck_obstacle_by_behaviour:
        share.(Enum.count(pr, & &1.holds_puck_obstacle_by_behaviour)),
      trials_with_puck_near_steps: Enum.count(pr, &(&1.puck_near_steps > 0)),
      puck_near_steps: mean2(Enum.map(pr, & &1.puck_near_steps)),
      puck_near_antibody_share: mean2(Enum.flat_map(pr, &List.wrap(&1.puck_near_antibody_share))),
      share_with_puck_and_obstacle: share.(Enum.count(pr, & &1.holds_puck_and_obstacle)),
      puck_steps: steps,
      puck_ab_steps: ab_steps,
      puck_use_pooled: if(steps > 0, do: Float.round(ab_steps / steps, 3)),
      puck_use_by_trial: Enum.map(pr, &(&1.puck_use && Float.round(&1.puck_use, 3))),
      test_objective: mean2(Enum.map(pr, &(&1.test_objective || 0.0))),
      test_objective_by_trial: Enum.map(pr, &Float.round(&1.test_objective || 0.0, 4)),
      test_objective_product: mean2(Enum.map(pr, &(&1.test_objective_product || 0.0))),
      puck_champion_gain_by_trial:
        Enum.map(pr, &(&1.puck_champion_gain && Float.round(&1.puck_champion_gain, 3))),
      trials_puck_champion_improved: Enum.count(pr, & &1.puck_champion_improved),
      share_puck_champion_improved: share.(Enum.count(pr, & &1.puck_champion_improved)),
      wall_free_episodes_by_trial: Enum.map(pr, & &1.wall_free_episodes),
      light_episodes_by_trial: Enum.map(pr, & &1.light_episodes),
      puck_kept_episodes_by_trial: Enum.map(pr, & &1.puck_kept_episodes),
      trials_failing_a_behaviour: Enum.count(pr, & &1.fails_a_behaviour),
      first10_failing_a_behaviour: Enum.count(first10, & &1.probes.fails_a_behaviour),
      first10_trials: length(first10),
      puck_ultrasonic_min_by_trial: Enum.map(pr, &List.first(&1.puck_ultrasonic)),
      stalled_share: mean2(Enum.map(pr, & &1.trace.stalled_share)),
      full_period_share: mean2(Enum.map(pr, & &1.trace.full_share)),
      fitness_stalled: mean2(Enum.flat_map(pr, &List.wrap(&1.trace.fitness_stalled))),
      fitness_moving: mean2(Enum.flat_map(pr, &List.wrap(&1.trace.fitness_moving))),
      champions: pr |> Enum.map(& &1.trace.champions) |> Enum.sum(),
      champions_stalled: pr |> Enum.map(& &1.trace.champions_stalled) |> Enum.sum(),
      wall_champions: pr |> Enum.map(& &1.trace.wall_champions) |> Enum.sum(),
      wall_champions_stalled: pr |> Enum.map(& &1.trace.wall_champions_stalled) |> Enum.sum(),
      wall_champion_steps: mean2(Enum.flat_map(pr, &List.wrap(&1.trace.wall_champion_steps))),
      wall_free_episodes: mean2(Enum.map(pr, & &1.wall_free_episodes)),
      light_episodes: mean2(Enum.map(pr, & &1.light_episodes)),
      puck_kept_episodes: mean2(Enum.map(pr, & &1.puck_kept_episodes))
    }
  end

  # the criteria of the pre-registration of 2026-12-06 (issue 46, item 6): the fixed
  # evaluation period against its step-matched baseline, the stall, the behaviour probe
  defp fixed_period(arms) do
    fixed = arms["s2_immune_fixed"]
    region = arms["s2_immune"]

    learning =
      Stats.mann_whitney(
        fixed.test_objective_by_trial,
        arms["s2_monolithic_matched_fixed"].test_objective_by_trial,
        method: :exact
      )

    stall = fn a -> a.wall_champions_stalled / max(a.wall_champions, 1) end

    %{
      learning_p_value: Float.round(learning.p_value, 6),
      learning: learning.p_value < 0.05,
      wall_champions_stalled_share_fixed: Float.round(stall.(fixed), 3),
      wall_champions_stalled_share_region: Float.round(stall.(region), 3),
      stall_lower: stall.(fixed) < stall.(region),
      puck_obstacle_by_behaviour_fixed: fixed.share_puck_obstacle_by_behaviour >= 0.8,
      puck_obstacle_by_behaviour_region: region.share_puck_obstacle_by_behaviour >= 0.8
    }
  end

  # the pre-registered criteria (they are S2's; computed for every scenario, the
  # monolithic one for S2 and S3)
  defp done_means(main, mono, obj, arms) do
    mono_fail =
      arms
      |> Enum.filter(fn {k, _} -> String.ends_with?(k, "_monolithic") end)
      |> Map.new(fn {k, a} ->
        {k, a.first10_trials >= 10 and a.first10_failing_a_behaviour >= 8}
      end)

    %{
      structure:
        if(main,
          do: main.share_with_puck_and_obstacle >= 0.8 and (main.puck_use_pooled || 0.0) >= 0.75
        ),
      learning:
        if(main && obj,
          do: obj.p_value < 0.05 and main.share_puck_champion_improved >= 0.7
        ),
      monolithic_fails_a_probe_8_of_10: mono_fail,
      monolithic_arm: mono && mono.first10_failing_a_behaviour
    }
  end
end
