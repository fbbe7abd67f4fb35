defmodule TartarusImmune.Evolution.Experiment do
  @moduledoc """
  The embodied-evolution experiments of thesis ch. 7 (`mix tartarus.evolve`), each a
  `TartarusEmu.Sweep` over seeds: this module is their door (options, `run/1`, the
  registry); each experiment is a module of its own:

  | experiment | module | arms |
  |---|---|---|
  | `s1`, `s2`, `s3`, `monolithic` | `TartarusImmune.Evolution.Experiment.Trials` | `<scenario>_<design>` |
  | `s2_fixed` | `TartarusImmune.Evolution.Experiment.Trials` | `s2_<design>`, `s2_<design>_fixed` |
  | `robots3` | `TartarusImmune.Evolution.Experiment.Robots3` | `none`, `broadcast`, `ipkt` |
  | `robots3_dynamic` | `TartarusImmune.Evolution.Experiment.Robots3` | also `broadcast_dynamic`, `ipkt_dynamic` |
  | `sharing` | `TartarusImmune.Evolution.Experiment.SharingSizes` | `<n>: <scheme>` |
  | `density` | `TartarusImmune.Evolution.Experiment.Density` | `n<n> d<degree>: <scheme>` |


  `s1`, `s2`, `s3` (§7.3.1, Figs. 7.3-7.5): `trials` runs of one robot learning the
  scenario on the arena with the immune algorithm and, beside each, the monolithic
  baseline (§7.4.1) on the same seed (`TartarusImmune.Evolution.Embodied`); `monolithic`:
  the baseline alone on all three scenarios. A step is one trial. `recovery`, `period`,
  `min_period`, `loop`, `max_inner`, `sigma_max`, `puck_reward` and `score` are passed to
  every run; their defaults are the thesis as printed (docs/evolution.md, the
  pre-registration of 2026-11-27): the inner loop of Algorithm 5, an evaluation stopped
  at once when the epitope leaves the region, Eqs. 7.1-7.3 summed over the period with
  `f_puck = b_puck + v_trans`. The summary compares the two designs' test
  success over the trials with a one-sided Mann-Whitney U test
  (`TartarusTools.Stats.mann_whitney/3`, exact): `mann_whitney_u`, `p_value` (immune better
  than monolithic), and `immune_beats_monolithic` is true when `p_value < 0.05`.

  `sharing` (§7.4.3, Fig. 7.6): for each network size, social learning by
  broadcast (`b-cast`) against 1, 2, 4, ... intelligent packets (`iPkt-x`, x = n/20, n/10
  and n/5, at least 1), `trials` runs each (seeds `seed`, `seed + 1`, ...); see
  `TartarusImmune.Evolution.Sharing` for what one run does (and `none`, no sharing, as
  the baseline) and how `gamma_avg` and `Omega`
  are measured. A step of the scenario is one (size, scheme) point.

  `density` (ch. 8's dense-versus-sparse claim): the sharing experiment at each size of
  `sizes` and each number of link stubs per node of `degrees`, broadcast against Fig.
  7.6's three iPkt counts; see `TartarusImmune.Evolution.Experiment.Density`.

  `robots3` (§7.4.2): three robots learning S3 in one arena, sharing antibodies by
  broadcast, by a packet agent, or not at all (`TartarusImmune.Evolution.Collective`), on
  the same seeds; a step is one trial.

  Every experiment writes (in `out`) what it always wrote (`runs.csv`, its charts, the
  series as `series.csv` and one CSV and SVG per series, `summary.json`, `summary.md`)
  and, from the sweep, box plots per arm of its metrics; the summary keeps the keys of
  the runner (`scenario`, `seed`, `steps`: points run, `setup_ms`, `run_ms`) and gets the
  sweep's `sweep` (aggregates per arm and the tests). A step of the series is a trial
  (`s1`-`s3`, `monolithic`, `robots3`) or a (size, scheme) point (`sharing`).
  """

  alias Tartarus.Clock
  alias TartarusEmu.{Scenario, Sweep}
  alias TartarusImmune.Evolution.Experiment.{Density, Robots3, SharingSizes, Trials}
  alias TartarusTools.Report

  @experiments %{
    s1: Trials,
    s2: Trials,
    s2_fixed: Trials,
    s3: Trials,
    monolithic: Trials,
    robots3: Robots3,
    robots3_dynamic: Robots3,
    sharing: SharingSizes,
    density: Density
  }

  @schema [
    experiment: [
      type:
        {:in,
         [:s1, :s2, :s2_fixed, :s3, :monolithic, :robots3, :robots3_dynamic, :sharing, :density]},
      default: :sharing,
      doc: "which experiment"
    ],
    sizes: [
      type: {:list, :pos_integer},
      default: [20, 40, 80],
      doc: "`sharing`, `density`: network sizes"
    ],
    degrees: [
      type: {:list, :pos_integer},
      default: [1, 2, 3, 5, 8, 12, 16],
      doc: "`density`: link stubs per node (potential neighbours at most), one point each"
    ],
    trials: [type: :pos_integer, default: 10, doc: "runs per point (seeds seed, seed + 1, ...)"],
    p: [
      type: :probability,
      default: 0.1,
      doc:
        "`sharing`, `density`: per-iteration link flap probability; `robots3_dynamic`: the same per tick of 3 s"
    ],
    max_iterations: [
      type: :pos_integer,
      default: 3000,
      doc: "`sharing`, `density`: a run gives up after this"
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
      default: 1,
      doc:
        "`s1`-`s3`, `monolithic`: steps before leaving the active region ends an evaluation (1: at once, as the thesis)"
    ],
    loop: [
      type: {:in, [:while_in_region, :once]},
      default: :while_in_region,
      doc:
        "`s1`-`s3`: Algorithm 5's lines 22-24 as printed (evaluate and evolve again while the epitope stays in the active region) or one evaluation per iteration (`Embodied`)"
    ],
    max_inner: [
      type: :pos_integer,
      default: 10,
      doc: "`s1`-`s3`, `--loop while_in_region`: evaluation periods per iteration at most"
    ],
    sigma_max: [
      type: {:range, 1.0e-3, 100},
      default: 4.0,
      doc:
        "`s1`-`s3`, `monolithic`: the (1+1)-online strategy's sigma ceiling (Bredeche et al. 2009: 4)"
    ],
    matched: [
      type: :boolean,
      default: true,
      doc:
        "`s1`, `s2`: add the arm `<scenario>_monolithic_matched`, the baseline trained for as many scored steps as the immune robot drove on the same seed (the default since 2026-12-06; `--no-matched` leaves it out)"
    ],
    puck_reward: [
      type: {:in, [:product, :sum]},
      default: :sum,
      doc:
        "`s2`, `s3`, `monolithic`, `robots3`: the reading of f_puck, `sum` as printed (`Objective`)"
    ],
    score: [
      type: {:in, [:per_step, :total]},
      default: :total,
      doc:
        "`s1`-`s3`, `monolithic`: an evaluation's fitness summed over the period as Eqs. 7.1-7.3 print it, or per step (`Embodied`)"
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
  The module of each experiment (the registry `run/1` and `mix tartarus.evolve` read).

      iex> TartarusImmune.Evolution.Experiment.experiments()[:robots3]
      TartarusImmune.Evolution.Experiment.Robots3
  """
  @spec experiments() :: %{atom() => module()}
  def experiments, do: @experiments

  @doc """
  Runs an experiment. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, %{summary:, series:, out:, files:}}` or `{:error, message}`.
  """
  @spec run(keyword()) :: {:ok, TartarusEmu.Scenario.result()} | {:error, term()}
  def run(opts \\ []) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "#{inspect(__MODULE__)}.run/1") do
      p = Map.new(opts)
      module = Map.fetch!(@experiments, p.experiment)

      out =
        Keyword.get_lazy(opts, :out, fn ->
          Report.default_out_dir("evolve-#{opts[:experiment]}")
        end)

      t0 = Clock.machine_time(:millisecond)
      spec = module.spec(p)

      # the runner's keys, as when the experiment was a Scenario
      runner = fn r ->
        %{
          scenario: "evolve",
          seed: p.seed,
          steps: module.points(p),
          setup_ms: 0,
          run_ms: Clock.machine_time(:millisecond) - t0
        }
        |> Map.merge(module.summary(runs(r), p))
      end

      write = fn dir, r ->
        Scenario.write_series(dir, "evolve", module.series(runs(r), p)) ++
          module.write(dir, runs(r), p)
      end

      spec =
        Map.merge(spec, %{
          name: "evolve-#{p.experiment}",
          title:
            "Embodied evolution (thesis ch. 7): sharing controllers by broadcast or by iPkts",
          summary: runner,
          write: write
        })

      {:ok, r} = Sweep.run(spec, out: out, quiet: p.quiet)
      series = module.series(runs(r), p)
      {:ok, %{summary: r.summary, series: series, out: r.out, files: r.files}}
    end
  end

  # the runs' results, in the sweep's order
  defp runs(sweep), do: Enum.map(sweep.runs, & &1.summary)

  @doc "See `TartarusImmune.Evolution.Experiment.Shared.schemes/1`."
  defdelegate schemes(n), to: TartarusImmune.Evolution.Experiment.Shared

  @doc "See `TartarusImmune.Evolution.Experiment.Shared.label/1`."
  defdelegate label(scheme), to: TartarusImmune.Evolution.Experiment.Shared
end
