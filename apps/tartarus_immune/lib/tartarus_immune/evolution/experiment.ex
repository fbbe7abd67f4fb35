defmodule TartarusImmune.Evolution.Experiment do
  @moduledoc """
  The embodied-evolution experiments of thesis ch. 7 as a `TartarusEmu.Scenario`
  (`mix tartarus.evolve`).

  `s1`, `s2`, `s3` (§7.3.1, Figs. 7.3-7.5): `trials` runs of one robot learning the
  scenario on the arena with the immune algorithm and, beside each, the monolithic
  baseline (§7.4.1) on the same seed (`TartarusImmune.Evolution.Embodied`); `monolithic`:
  the baseline alone on all three scenarios. A step is one trial. `recovery`, `period`,
  `min_period`, `puck_reward` and `score` are passed to every run. The summary compares the two designs' test
  success over the trials with a one-sided Mann-Whitney U test
  (`TartarusTools.Stats.mann_whitney/3`, exact): `mann_whitney_u`, `p_value` (immune better
  than monolithic), and `immune_beats_monolithic` is true when `p_value < 0.05`.

  `sharing` (§7.4.3, Fig. 7.6): for each network size, social learning by
  broadcast (`b-cast`) against 1, 2, 4, ... intelligent packets (`iPkt-x`, x = n/20, n/10
  and n/5, at least 1), `trials` runs each (seeds `seed`, `seed + 1`, ...); see
  `TartarusImmune.Evolution.Sharing` for what one run does (and `none`, no sharing, as
  the baseline) and how `gamma_avg` and `Omega`
  are measured. A step of the scenario is one (size, scheme) point.

  `robots3` (§7.4.2): three robots learning S3 in one arena, sharing antibodies by
  broadcast, by a packet agent, or not at all (`TartarusImmune.Evolution.Collective`), on
  the same seeds; a step is one trial.
  """
  @behaviour TartarusEmu.Scenario

  alias TartarusImmune.Evolution.{Collective, Embodied, Sharing}
  alias TartarusTools.{Report, Series, Stats, SVG}

  @schema [
    experiment: [
      type: {:in, [:s1, :s2, :s3, :monolithic, :robots3, :sharing]},
      default: :sharing,
      doc: "which experiment"
    ],
    sizes: [type: {:list, :pos_integer}, default: [20, 40, 80], doc: "`sharing`: network sizes"],
    trials: [type: :pos_integer, default: 10, doc: "runs per point (seeds seed, seed + 1, ...)"],
    p: [type: :probability, default: 0.1, doc: "`sharing`: per-iteration link flap probability"],
    max_iterations: [
      type: :pos_integer,
      default: 3000,
      doc: "`sharing`: a run gives up after this"
    ],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    recovery: [
      type: :non_neg_integer,
      default: 0,
      doc: "`s1`-`s3`, `monolithic`: unscored steps before each evaluation (`Embodied`)"
    ],
    period: [
      type: :pos_integer,
      default: 30,
      doc: "`s1`-`s3`, `monolithic`: steps per evaluation at most"
    ],
    min_period: [
      type: :pos_integer,
      default: 10,
      doc: "`s1`-`s3`, `monolithic`: steps before leaving the active region ends an evaluation"
    ],
    puck_reward: [
      type: {:in, [:product, :sum]},
      default: :product,
      doc: "`s2`, `s3`, `monolithic`, `robots3`: the reading of f_puck (`Objective`)"
    ],
    score: [
      type: {:in, [:per_step, :total]},
      default: :per_step,
      doc:
        "`s1`-`s3`, `monolithic`: an evaluation's fitness per step, or summed over the period as Eqs. 7.1-7.3 print it (`Embodied`)"
    ],
    seed: [type: :integer, default: 1, doc: "seed"],
    out: [
      type: :any,
      doc: "output directory (default `results/evolve-<experiment>-<UTC timestamp>`), or false"
    ],
    quiet: [type: :boolean, default: false, doc: "no progress line"]
  ]

  @doc "The options of `run/1`."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Runs an experiment. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, %{summary:, series:, out:, files:}}` (see `TartarusEmu.Scenario.run/2`) or
  `{:error, message}`.
  """
  @spec run(keyword()) :: {:ok, TartarusEmu.Scenario.result()} | {:error, term()}
  def run(opts \\ []) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "#{inspect(__MODULE__)}.run/1") do
      out =
        Keyword.get_lazy(opts, :out, fn ->
          Report.default_out_dir("evolve-#{opts[:experiment]}")
        end)

      points =
        if opts[:experiment] == :sharing,
          do: for(n <- opts[:sizes], scheme <- schemes(n), do: {n, scheme}),
          else: Enum.to_list(0..(opts[:trials] - 1))

      TartarusEmu.Scenario.run(__MODULE__,
        seed: opts[:seed],
        out: out,
        quiet: opts[:quiet],
        steps: length(points),
        params: Keyword.drop(opts, [:seed, :out, :quiet]),
        points: points
      )
    end
  end

  @doc """
  The schemes compared on an n-node network: no sharing (the baseline: how fast the
  nodes get there on their own), broadcast, then iPkts in three numbers proportional to n.

      iex> TartarusImmune.Evolution.Experiment.schemes(20)
      [:none, :broadcast, {:ipkt, 1}, {:ipkt, 2}, {:ipkt, 4}]
      iex> TartarusImmune.Evolution.Experiment.schemes(80)
      [:none, :broadcast, {:ipkt, 4}, {:ipkt, 8}, {:ipkt, 16}]
  """
  @spec schemes(pos_integer()) :: [:none | :broadcast | {:ipkt, pos_integer()}]
  def schemes(n),
    do: [:none, :broadcast | Enum.map([20, 10, 5], &{:ipkt, max(1, div(n, &1))})] |> Enum.uniq()

  @doc "A scheme's label: `none`, `b-cast` or `iPkt-x`."
  @spec label(:none | :broadcast | {:ipkt, pos_integer()}) :: String.t()
  def label(:none), do: "none"
  def label(:broadcast), do: "b-cast"
  def label({:ipkt, x}), do: "iPkt-#{x}"

  @impl true
  def name, do: "evolve"

  @impl true
  def title, do: "Embodied evolution (thesis ch. 7): sharing controllers by broadcast or by iPkts"

  @impl true
  def setup(opts),
    do:
      {:ok,
       %{
         p: Map.new(opts.params),
         seed: opts.seed,
         points: opts.points,
         runs: [],
         series: Series.new()
       }}

  @impl true
  def step(%{p: %{experiment: :robots3}} = state, k) do
    trial = Enum.at(state.points, k - 1)

    runs =
      for scheme <- [:none, :broadcast, :ipkt] do
        {:ok, r} =
          Collective.run(
            scheme: scheme,
            seed: state.seed + trial,
            puck_reward: state.p.puck_reward
          )

        Map.put(r, :trial, trial)
      end

    series =
      Enum.reduce(runs, state.series, fn r, series ->
        Series.record(series, :"test_success_robots3_#{r.scheme}", trial + 1, r.test_success)
      end)

    %{state | runs: state.runs ++ runs, series: series}
  end

  def step(%{p: %{experiment: exp}} = state, k) when exp != :sharing do
    trial = Enum.at(state.points, k - 1)
    seed = state.seed + trial

    scenarios = if exp == :monolithic, do: [:s1, :s2, :s3], else: [exp]
    designs = if exp == :monolithic, do: [:monolithic], else: [:immune, :monolithic]

    runs =
      for sc <- scenarios, d <- designs do
        {:ok, r} =
          Embodied.run(
            scenario: sc,
            design: d,
            seed: seed,
            trace: trial == 0,
            recovery: state.p.recovery,
            period: state.p.period,
            min_period: state.p.min_period,
            puck_reward: state.p.puck_reward,
            score: state.p.score
          )

        Map.merge(r, %{trial: trial})
      end

    series =
      Enum.reduce(runs, state.series, fn r, series ->
        Series.record(
          series,
          :"test_success_#{r.scenario}_#{r.design}",
          trial + 1,
          r.test_success
        )
      end)

    %{state | runs: state.runs ++ runs, series: series}
  end

  def step(state, k) do
    {n, scheme} = Enum.at(state.points, k - 1)
    p = state.p

    runs =
      for trial <- 0..(p.trials - 1) do
        {kind, x} = if is_atom(scheme), do: {scheme, 1}, else: scheme

        {:ok, r} =
          Sharing.run(
            nodes: n,
            scheme: kind,
            ipkts: x,
            p: p.p,
            max_iterations: p.max_iterations,
            mode: p.mode,
            seed: state.seed + trial
          )

        Map.merge(r, %{label: label(scheme), trial: trial, wall_ms: nil})
      end

    series =
      state.series
      |> Series.record(:"gamma_avg_n#{n}", k, mean2(Enum.map(runs, & &1.gamma_avg)))
      |> Series.record(:"omega_n#{n}", k, mean2(omegas(runs)))

    %{state | runs: state.runs ++ runs, series: series}
  end

  @impl true
  def done?(state, k), do: k >= length(state.points)

  @impl true
  def series(state), do: state.series

  @impl true
  def write(%{p: %{experiment: :robots3}} = state, dir) do
    rows =
      for r <- state.runs, p <- r.per_robot do
        c = r.communications

        [
          r.scheme,
          r.trial,
          p.robot,
          p.antibodies,
          p.external_selections,
          p.test_success,
          c.broadcast_messages + c.broadcasts_received + c.departures + c.arrivals
        ]
      end

    csv = Path.join(dir, "runs.csv")

    File.write!(
      csv,
      Report.to_csv(
        ~w(scheme trial robot antibodies external_selections test_success communications),
        rows
      )
    )

    [csv]
  end

  def write(%{p: %{experiment: exp}} = state, dir) when exp != :sharing do
    rows =
      for r <- state.runs,
          do: [
            r.scenario,
            r.design,
            r.trial,
            r.antibodies,
            r.switches,
            Float.round(r.final_fitness, 4),
            r.test_success
          ]

    csv = Path.join(dir, "runs.csv")

    File.write!(
      csv,
      Report.to_csv(
        ~w(scenario design trial antibodies switches final_fitness test_success),
        rows
      )
    )

    curves =
      for r <- state.runs, r.trial == 0 do
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
              "#{String.upcase(to_string(r.scenario))}, #{r.design}: the robot's path while learning"
          )
        )

        [file, traj]
      end

    [csv | List.flatten(curves)]
  end

  def write(state, dir) do
    rows =
      for r <- state.runs,
          do: [
            r.nodes,
            r.label,
            r.trial,
            r.gamma_avg,
            r.omega,
            r.first_solved_at,
            r.converged_at,
            r.iterations
          ]

    csv = Path.join(dir, "runs.csv")

    File.write!(
      csv,
      Report.to_csv(
        ~w(nodes scheme trial gamma_avg omega first_solved_at converged_at iterations),
        rows
      )
    )

    bars = fn key ->
      for {n, scheme} <- state.points do
        runs = Enum.filter(state.runs, &(&1.nodes == n and &1.label == label(scheme)))

        v =
          if key == :gamma_avg,
            do: mean2(Enum.map(runs, & &1.gamma_avg)),
            else: mean2(omegas(runs))

        {"#{n}: #{label(scheme)}", v || 0}
      end
    end

    gamma = Path.join(dir, "gamma_avg.svg")
    omega = Path.join(dir, "omega.svg")

    File.write!(
      gamma,
      SVG.bar_chart(bars.(:gamma_avg),
        title: "Communications per node until convergence (gamma_avg, Fig. 7.6)",
        y_label: "messages sent + received per node"
      )
    )

    File.write!(
      omega,
      SVG.bar_chart(bars.(:omega),
        title: "Convergence count Omega: iterations from the first solution to 90% (Fig. 7.6)",
        y_label: "iterations"
      )
    )

    [csv, gamma, omega]
  end

  @impl true
  def summary(%{p: %{experiment: :robots3}} = state) do
    by = fn f ->
      Map.new([:none, :broadcast, :ipkt], fn scheme ->
        {to_string(scheme), f.(Enum.filter(state.runs, &(&1.scheme == scheme)))}
      end)
    end

    comm = fn r -> r.communications |> Map.values() |> Enum.sum() end

    %{
      experiment: "robots3",
      trials: state.p.trials,
      puck_reward: to_string(state.p.puck_reward),
      test_success: by.(fn runs -> mean2(Enum.map(runs, & &1.test_success)) end),
      antibodies: by.(fn runs -> mean2(for r <- runs, p <- r.per_robot, do: p.antibodies) end),
      external_selections:
        by.(fn runs -> mean2(for r <- runs, p <- r.per_robot, do: p.external_selections) end),
      communications_per_robot: by.(fn runs -> mean2(for r <- runs, do: comm.(r) / r.robots) end)
    }
  end

  def summary(%{p: %{experiment: exp}} = state) when exp != :sharing do
    p = state.p
    arm = fn sc, d -> Enum.filter(state.runs, &(&1.scenario == sc and &1.design == d)) end
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

  def summary(state) do
    p = state.p

    by = fn f ->
      for {n, scheme} <- state.points, reduce: %{} do
        acc ->
          runs = Enum.filter(state.runs, &(&1.nodes == n and &1.label == label(scheme)))

          Map.update(
            acc,
            to_string(n),
            %{label(scheme) => f.(runs)},
            &Map.put(&1, label(scheme), f.(runs))
          )
      end
    end

    gamma = by.(fn runs -> mean2(Enum.map(runs, & &1.gamma_avg)) end)
    omega = by.(fn runs -> mean2(omegas(runs)) end)

    %{
      experiment: to_string(p.experiment),
      trials: p.trials,
      sizes: p.sizes,
      p: p.p,
      mode: to_string(p.mode),
      gamma_avg: gamma,
      omega: omega,
      omega_median: by.(fn runs -> Stats.median(omegas(runs)) end),
      converged_runs: by.(fn runs -> Enum.count(runs, & &1.converged) end),
      iterations_to_converge:
        by.(fn runs -> mean2(for r <- runs, r.converged, do: r.converged_at) end),
      ipkt_fewer_communications_at_every_size:
        Enum.all?(gamma, fn {_n, g} ->
          Enum.all?(g, fn {l, v} -> l in ["b-cast", "none"] or v < g["b-cast"] end)
        end),
      more_ipkts_lower_omega:
        Map.new(omega, fn {n, o} ->
          vs =
            o
            |> Enum.filter(&match?({"iPkt-" <> _, _}, &1))
            |> Enum.sort_by(&ipkts(elem(&1, 0)))
            |> Enum.map(&elem(&1, 1))

          {n, vs == Enum.sort(vs, :desc)}
        end),
      antibodies: nil,
      test_success: nil
    }
  end

  defp ipkts("iPkt-" <> x), do: String.to_integer(x)

  defp omegas(runs), do: for(r <- runs, r.omega != nil, do: r.omega)

  # the mean to 2 decimals, nil for none
  defp mean2(xs), do: (m = Stats.mean(xs)) && Float.round(m, 2)
end
