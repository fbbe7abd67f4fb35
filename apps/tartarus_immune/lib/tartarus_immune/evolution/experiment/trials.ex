defmodule TartarusImmune.Evolution.Experiment.Trials do
  @moduledoc """
  `s1`, `s2`, `s3` and `monolithic` of `mix tartarus.evolve` (thesis §7.3.1, §7.4.1,
  Figs. 7.3-7.5): `trials` runs of one robot learning a scenario with the immune
  algorithm and, beside each, the monolithic baseline on the same seed
  (`TartarusImmune.Evolution.Embodied`); `monolithic` runs the baseline alone on all
  three scenarios. A sweep (`TartarusEmu.Sweep`): an arm is `<scenario>_<design>`, the
  seeds are `seed + trial`; the first trial keeps its trace (fitness curves and the
  robot's path). The summary tests "immune better than monolithic" on test success with
  an exact one-sided Mann-Whitney U test. Run it with
  `TartarusImmune.Evolution.Experiment.run/1`.
  """

  import TartarusImmune.Evolution.Experiment.Shared, only: [mean2: 1]

  alias TartarusImmune.Evolution.Embodied
  alias TartarusTools.{Series, Stats, SVG}

  @doc "The sweep (arms, seeds, run, metrics, tests, rows of `runs.csv`) for options `p`."
  @spec spec(map()) :: map()
  def spec(p) do
    exp = p.experiment
    scenarios = if exp == :monolithic, do: [:s1, :s2, :s3], else: [exp]
    designs = if exp == :monolithic, do: [:monolithic], else: [:immune, :monolithic]
    arms = for sc <- scenarios, d <- designs, do: {"#{sc}_#{d}", %{scenario: sc, design: d}}

    tests =
      if exp == :monolithic,
        do: [],
        else: [{"#{exp}_immune", :greater, "#{exp}_monolithic", :test_success, [method: :exact]}]

    %{
      arms: arms,
      seeds: Enum.map(0..(p.trials - 1), &(p.seed + &1)),
      run: fn arm, seed -> run_one(arm.opts, seed, p) end,
      metrics: [test_success: :test_success, antibodies: :antibodies, switches: :switches],
      tests: tests,
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

  defp run_one(%{scenario: sc, design: d}, seed, p) do
    trial = seed - p.seed

    {:ok, r} =
      Embodied.run(
        scenario: sc,
        design: d,
        seed: seed,
        trace: trial == 0,
        recovery: p.recovery,
        period: p.period,
        min_period: p.min_period,
        puck_reward: p.puck_reward,
        score: p.score
      )

    Map.merge(r, %{trial: trial})
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
        :"test_success_#{r.scenario}_#{r.design}",
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
        file = Path.join(dir, "curve_#{r.scenario}_#{r.design}.svg")

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
              "#{String.upcase(to_string(r.scenario))} #{r.design}: fitness by antibody (#{r.switches} switches#{light})",
            x_label: "iteration",
            y_label: "fitness per step"
          )
        )

        traj = Path.join(dir, "trajectory_#{r.scenario}_#{r.design}.svg")

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

    List.flatten(curves)
  end

  @doc "The summary: per arm, and the test of immune against monolithic."
  @spec summary([map()], map()) :: map()
  def summary(runs, p) do
    exp = p.experiment
    arm = fn sc, d -> Enum.filter(runs, &(&1.scenario == sc and &1.design == d)) end
    key = fn sc, d -> "#{sc}_#{d}" end

    arms =
      for sc <- [:s1, :s2, :s3],
          d <- [:immune, :monolithic],
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
           s3
         )}
      end

    main = if exp == :monolithic, do: nil, else: arms[key.(exp, :immune)]
    mono = if exp == :monolithic, do: nil, else: arms[key.(exp, :monolithic)]

    test =
      main && mono &&
        Stats.mann_whitney(main.test_success_by_trial, mono.test_success_by_trial, method: :exact)

    %{
      experiment: to_string(exp),
      trials: p.trials,
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
end
