defmodule Mix.Tasks.Tartarus.Evolve do
  @shortdoc "Embodied evolution (thesis ch. 7): sharing controllers by broadcast or by iPkts"
  @moduledoc """
  Runs the embodied-evolution experiments of thesis ch. 7 (see
  `TartarusImmune.Evolution.Experiment`).

      mix tartarus.evolve [--experiment sharing|density|s1|s2|s2_fixed|s3|monolithic|robots3|robots3_dynamic]
                          [--seeds 10] [--sizes 20,40,80] [--degrees 1,2,3,5,8,12,16]
                          [--p 0.1] [--max-iterations 3000]
                          [--mode virtual|peer] [--recovery 0] [--period 30]
                          [--loop while_in_region|once] [--max-inner 10]
                          [--min-period 1] [--puck-reward sum|product]
                          [--score total|per_step] [--sigma-max 4.0] [--no-matched]
                          [--seed 1] [--out DIR] [--json]

  `s1`, `s2`, `s3` (§7.3.1): one robot on the arena (2 m x 2 m, the light in the middle,
  10 yellow pucks for S2 and S3) learns phototaxis with obstacle avoidance (S1), pushing
  pucks towards the light (S2), or both with the light switched off, on and off again (S3,
  where it must repel pucks when the light is off), with the immune algorithm (epsilon
  0.45, 0.4, 0.25; 200, 500, 500 iterations) and, on the same seed, one monolithic
  controller (200, 400, 400 iterations); then 10 test episodes of 30 s from fresh poses
  with the learnt controllers frozen. `monolithic` runs the baseline alone on all three.
  The defaults are the thesis as printed (docs/evolution.md, "Pre-registration of
  2026-11-27"). Each evaluation of up to `--period` steps of 0.1 s (30) follows
  `--recovery` unscored steps (0, as in the thesis; 20 is Bredeche et al.'s recovery
  period) and, for the immune robot, ends when the sensors leave the antibody's active
  region after `--min-period` steps (1: at once). `--loop while_in_region` (default) is
  Algorithm 5's lines 22-24: an iteration evaluates and evolves the selected antibody
  again, period after period, while the epitope stays in its region (at most
  `--max-inner` periods, 10); `--loop once` is one evaluation per iteration. The
  monolithic robot evaluates once per iteration either way. `--score` is an evaluation's
  fitness: summed over the period (`total`, default, Eqs. 7.1-7.3 as printed) or per
  step (`per_step`). `--puck-reward` chooses the reading of Eq. 7.2's f_puck (S2, S3 with
  the light on, `robots3`): `sum` (default), `b_puck + v_trans` as printed; `product`,
  `b_puck * v_trans`, moving with a puck in the gripper (see
  `TartarusImmune.Evolution.Objective`). `--sigma-max` is the (1+1)-online strategy's
  sigma ceiling (4.0, Bredeche et al.'s). `s1` and `s2` have the arm
  `<scenario>_monolithic_matched` (since 2026-12-06 by default; `--no-matched` leaves it
  out): the baseline trained for as many scored steps as the immune robot drove on the
  same seed; the summary's `comparison` says which, `matched_objective_p_value` is the
  step-matched test.

  `s2_fixed` (issue 46): S2 with the fixed evaluation period t' (`--period`, 30 steps) as
  a labelled arm beside the region-ended one: arms `s2_immune` (a period ends when the
  epitope leaves the antibody's region), `s2_immune_fixed` (every period runs its t'
  steps; the region is checked between periods, in training and test), each with its
  step-matched baseline (`s2_monolithic_matched`, `s2_monolithic_matched_fixed`), and the
  thesis's baseline `s2_monolithic`. Beside the probes above, per arm the behaviour probe
  (`trials_puck_obstacle_by_behaviour`: trials whose antibody run while a puck is held and
  an obstacle is nearer than 20 cm is not the one run with a puck and no such obstacle)
  and `done_means.fixed_period` (docs/evolution.md, pre-registration of 2026-12-06); the
  figure `s2_fixed.svg`.
  Success criteria: see `TartarusImmune.Evolution.Embodied`. Output: `runs.csv` (scenario,
  design, trial, antibodies, switches, final fitness, test success), for the first trial
  the evolution-selection curve (`curve_<scenario>_<design>.svg`: fitness per iteration, one
  colour per antibody, Figs. 7.3-7.5) and the robot's path (`trajectory_*.svg`). Summary:
  `arms` (per scenario and design: test_success, antibodies, switches, final_fitness, and
  for S3 the antibodies used with the light on, off and both, and in how many trials an
  antibody of the first light-off phase was used again in the second), `antibodies`,
  `test_success`, `test_success_monolithic`, `recovery`, `puck_reward`, `period`, `min_period`,
  `score`,
  `mann_whitney_u` and `p_value` (exact one-sided Mann-Whitney U test of the immune
  robot's per-trial test success against the baseline's), `immune_beats_monolithic`
  (`p_value < 0.05`); the probes of docs/evolution.md per arm (`evaluations`,
  `training_steps`, `puck_antibody_evaluations`, `trials_with_puck_and_obstacle`,
  `puck_use_pooled`, `test_objective` (Eq. 7.x per step in the test, printed f_puck),
  `trials_puck_champion_improved`, `first10_failing_a_behaviour`, `at_sigma_max`, the
  trace's `wall_champions_stalled`, ...), `objective_mann_whitney_u`, `objective_p_value`
  (immune higher on `test_objective`), `matched_objective_p_value`, `done_means` (the
  pre-registered criteria), `loop`, `max_inner`, `sigma_max`, `seeds`.

  `sharing` (§7.4.3, Fig. 7.6): robot nodes on a dynamic network (0-5 neighbours each,
  links flapping with probability `--p` per iteration) each evolve a 2-3-1 network for the
  OR gate with the (1+1)-online strategy and share what they find by broadcast (social
  learning) or by 1, 2, 4, ... intelligent packets (mobile agents moving conscientiously),
  against no sharing at all (`none`).
  For each size in `--sizes` and each scheme, `--trials` runs (seeds S, S+1, ...).

  Output (in `--out DIR`, default `results/evolve-<experiment>-<UTC timestamp>`):
  `runs.csv` (one row per run: nodes, scheme, trial, gamma_avg, omega, first_solved_at,
  converged_at, iterations), `gamma_avg.svg` and `omega.svg` (bars per size and scheme,
  Fig. 7.6), the series as CSV/SVG, `summary.json`, `summary.md`.

  Summary keys: `experiment, trials, sizes, p, mode, gamma_avg` and `omega` (size ->
  scheme -> mean over the converged runs), `omega_median, converged_runs,
  iterations_to_converge, ipkt_fewer_communications_at_every_size,
  more_ipkts_lower_omega` (size -> whether Omega falls as iPkts are added), `antibodies`
  and `test_success` (null for `sharing`), and the runner's `scenario, seed, steps,
  setup_ms, run_ms`, and `sweep` (`TartarusEmu.Sweep`: per-arm aggregates, box plots, and
  for `s1`-`s3` the test of immune against monolithic). With `--json` the last line printed is the summary as one JSON object.

  `density` (thesis ch. 8: iPkts for dense networks, broadcast for sparse ones): the
  `sharing` experiment at each size of `--sizes` (give one or two: `--sizes 40`) and each
  number of link stubs per node of `--degrees` (potential neighbours at most; Fig. 7.6
  has 5), broadcast against iPkts in Fig. 7.6's three numbers, `--seeds` runs each
  (`TartarusImmune.Evolution.Experiment.Density`). Output: `runs.csv` (nodes, degree,
  scheme, trial, potential and live mean degree, gamma_avg, omega, first_solved_at,
  converged_at, iterations), `density_ratio.svg` (gamma_avg of iPkts over broadcast
  against the live mean degree), `density_gamma.svg`, box plots per arm. Summary:
  `density` (size -> `by_degree` (degree -> live degree, gamma_avg, omega,
  converged_at and ratio per scheme, `p_bcast_fewer`, `p_ipkt_fewer`: one-sided
  Mann-Whitney of the n/10 iPkts' gamma_avg against broadcast's), `crossover` per iPkt
  count (the live degree where the ratio crosses 1, or null), `claim_reproduced`),
  `claim_reproduced` per size.

  `robots3` (§7.4.2): three robots learn S3 in one arena, each a host of an emulated
  network, sharing their best antibodies every 5 iterations by broadcast or by one packet
  agent, against no sharing, on the same seeds (`TartarusImmune.Evolution.Collective`).
  Output: `runs.csv` (one row per robot and run); summary `test_success`, `antibodies`,
  `external_selections` (shared antibodies a robot chose), `communications_per_robot`,
  `publications_per_robot`, `reached_per_publication` (robots a broadcast reached),
  `packet_stays_per_robot` (publications at which the packet agent had no link),
  `links_up`, `link_flaps`, each per arm, and `p_values` (exact one-sided Mann-Whitney U
  on test success: each sharing arm above `none`, static above dynamic).

  `robots3_dynamic` (issue 46): the same three robots, with two more arms,
  `broadcast_dynamic` and `ipkt_dynamic`, on the mesh whose links come and go: every 3 s
  (30 world steps) each link breaks, or heals, with probability `--p` (0.1); the figure
  `robots3_dynamic.svg`.

  `--seeds N` (or its old name `--trials N`) is the number of repetitions, on seeds
  `--seed`, `--seed` + 1, ...: the name `mix tartarus.select` uses for the same thing.
  """
  use TartarusTools.CLI

  alias TartarusImmune.Evolution.Experiment

  @task "tartarus.evolve"

  @impl true
  def run(argv) do
    schema =
      Experiment.schema()
      |> Keyword.drop([:quiet])
      |> Keyword.update!(:sizes, &Keyword.merge(&1, type: :string, default: "20,40,80"))
      |> Keyword.update!(
        :degrees,
        &Keyword.merge(&1, type: :string, default: "1,2,3,5,8,12,16")
      )
      |> Keyword.update!(:out, &Keyword.put(&1, :type, :string))
      |> Keyword.put(:json, type: :boolean, default: false, doc: "print the summary as JSON")

    opts = TartarusTools.CLI.options!(argv, schema, @task, synonyms: [seeds: :trials])
    json? = opts[:json]

    exp_opts =
      opts
      |> Keyword.drop([:json])
      |> Keyword.merge(
        sizes: parse_list!(opts[:sizes], "--sizes", 2),
        degrees: parse_list!(opts[:degrees], "--degrees", 1),
        quiet: json?
      )

    exp_opts = if opts[:out], do: exp_opts, else: Keyword.delete(exp_opts, :out)
    Mix.Task.run("app.start")

    case Experiment.run(exp_opts) do
      {:ok, %{summary: s, out: dir}} ->
        TartarusTools.CLI.report(s, [json: json?], fn s -> text(s, dir) end)

      {:error, message} ->
        TartarusTools.CLI.error!(@task, message)
    end
  end

  defp parse_list!(text, flag, least) do
    xs = text |> String.split(",", trim: true) |> Enum.map(&Integer.parse(String.trim(&1)))

    if xs != [] and Enum.all?(xs, &match?({n, ""} when n >= least, &1)),
      do: Enum.map(xs, &elem(&1, 0)),
      else:
        Mix.raise(
          "mix #{@task}: invalid value for #{flag}: expected comma-separated integers of at least #{least}, got: #{inspect(text)}"
        )
  end

  defp order("none"), do: -1
  defp order("b-cast"), do: 0
  defp order("iPkt-" <> x), do: String.to_integer(x)

  defp text(%{experiment: "robots3" <> _} = s, dir) do
    rows =
      for arm <- ["none", "broadcast", "ipkt", "broadcast_dynamic", "ipkt_dynamic"],
          Map.has_key?(s.test_success, arm) do
        "  #{String.pad_trailing(arm, 18)} test_success #{s.test_success[arm]}  antibodies #{s.antibodies[arm]}  shared chosen #{s.external_selections[arm]}  communications per robot #{s.communications_per_robot[arm]}  links up #{s.links_up[arm]}"
      end

    tests = for {t, pv} <- Enum.sort(s.p_values), do: "  test success #{t}: p = #{pv}"

    Enum.join(
      ["evolve: #{s.experiment}, #{s.trials} trials, f_puck #{s.puck_reward}"] ++
        rows ++ tests ++ ["  written to #{dir}"],
      "\n"
    )
  end

  defp text(%{arms: arms} = s, dir) do
    rows =
      for {arm, a} <- Enum.sort(arms) do
        extra =
          if Map.has_key?(a, :antibodies_light_on),
            do:
              "  antibodies light on/off/both #{a.antibodies_light_on}/#{a.antibodies_light_off}/#{a.antibodies_used_in_both}, re-used after the light came back in #{a.trials_reusing_after_return} trials",
            else: ""

        "  #{String.pad_trailing(arm, 14)} test_success #{a.test_success}  antibodies #{a.antibodies}  final fitness #{a.final_fitness}#{extra}"
      end

    test =
      if s.p_value,
        do: [
          "  immune better than monolithic on test success: one-sided Mann-Whitney U #{s.mann_whitney_u}, p = #{s.p_value}"
        ],
        else: []

    Enum.join(
      [
        "evolve: #{s.experiment}, #{s.trials} trials, f_puck #{s.puck_reward}, min period #{s.min_period}, score #{s.score}"
      ] ++
        rows ++ test ++ ["  written to #{dir}"],
      "\n"
    )
  end

  defp text(%{experiment: "density"} = s, dir) do
    rows =
      for {n, size} <- Enum.sort_by(s.density, &String.to_integer(elem(&1, 0))) do
        per_degree =
          for {d, b} <- Enum.sort_by(size.by_degree, &String.to_integer(elem(&1, 0))) do
            ratios =
              b.ratio
              |> Enum.sort_by(&order(elem(&1, 0)))
              |> Enum.map_join(", ", fn {l, r} -> "#{l} #{TartarusTools.CLI.show(r)}" end)

            "    stubs #{String.pad_leading(d, 2)} (live #{TartarusTools.CLI.show(b.live_degree)})  gamma_avg b-cast #{TartarusTools.CLI.show(b.gamma_avg["b-cast"])}  iPkt/b-cast #{ratios}  p(b-cast fewer) #{b.p_bcast_fewer}  p(iPkt fewer) #{b.p_ipkt_fewer}"
          end

        Enum.join(
          [
            "  #{n} nodes (judged: #{size.judged}); crossover (live degree) #{TartarusTools.CLI.show(size.crossover)}; claim reproduced: #{size.claim_reproduced}"
            | per_degree
          ],
          "\n"
        )
      end

    Enum.join(
      ["evolve: density, #{s.trials} trials per point, seeds #{s.seeds}"] ++
        rows ++ ["  written to #{dir}"],
      "\n"
    )
  end

  defp text(s, dir) do
    rows =
      for {n, g} <- Enum.sort_by(s.gamma_avg, &String.to_integer(elem(&1, 0))),
          {label, v} <- Enum.sort_by(g, &order(elem(&1, 0))) do
        "  #{String.pad_leading(n, 5)} nodes  #{String.pad_trailing(label, 10)} gamma_avg #{TartarusTools.CLI.show(v)}  Omega #{TartarusTools.CLI.show(s.omega[n][label])}"
      end

    Enum.join(
      ["evolve: #{s.experiment}, #{s.trials} trials per point"] ++
        rows ++
        [
          "  iPkts fewer communications than broadcast at every size: #{s.ipkt_fewer_communications_at_every_size}",
          "  more iPkts, lower Omega: #{TartarusTools.CLI.show(s.more_ipkts_lower_omega)}",
          "  written to #{dir}"
        ],
      "\n"
    )
  end
end
