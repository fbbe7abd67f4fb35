defmodule TartarusImmune.Select do
  @moduledoc """
  The experiments of thesis §6.5, each a set of `TartarusImmune.Experiment` runs, with
  their files and one summary (what `mix tartarus.select` prints).

  | experiment | runs | thesis |
  |---|---|---|
  | `table6_2` | P1-P4 on the grid, for `seeds` seeds | Table 6.2, Fig. 6.3 |
  | `sharing` | `set` with and without sharing, `seeds` seeds each | Fig. 6.11 |
  | `danger` | `set` with danger signals, without, and without sharing, `seeds` seeds each | Fig. 6.8 |
  | `fig6_8` | the pre-registered Fig. 6.8 (`TartarusImmune.Select.Fig68`): P4 on a 50-node grid, β 10, Eq. 6.5's lifetimes, the initial population on 10 hosts; the three arms of `danger`; adds the guard and the verdict | Fig. 6.8 |
  | `otfp` | `set` starting with Shell and Selection; Quick, Insertion, Merge, Heap added at `add_at` | Fig. 6.4 |
  | `nodes50` | P2 and P3 on `nodes` hosts (default 50), one seed | Fig. 6.5 |
  | `dynamic` | `set` (p4) on `nodes` (50) hosts that break off and reconnect with probability p per step, p in `ps` | Fig. 6.6 |
  | `influx` | `set` for η in `etas` | Fig. 6.7a |
  | `barrage` | `set` for β in `betas` | Fig. 6.7b |
  | `iot` | the temperature series on `nodes` hosts (default 50) | Fig. 6.10 |
  | `fig6_4b` | pre-registered (`TartarusImmune.Select.Fig64b`): `otfp` on P4 over several seeds; the mean learning curve, final shares, verdict | Fig. 6.4b |
  | `secondary` | pre-registered (`TartarusImmune.Select.Secondary`): P1, one barrage, then its copy at `repeat_at` once settled; time to suppression of the losers, first against copy | Fig. 6.3a |
  | `lspan` | pre-registered (`TartarusImmune.Select.Lspan`): `fig6_8`'s configuration with l_span 2, 3, 4 and no signals; the reach time of distressed hosts measured | Fig. 6.8 |

  Every run uses `TartarusImmune.Convergence` (leader share ≥ `share` for `hold` steps),
  in rounds (a step is one round: every host one iteration of Algorithm 4, every iPkt one
  move); the same convergence is also given in the thesis's log-server unit
  (`convergence_events`: sharing + executions logged by then; the arms' `events_mean`,
  `events_sd`), reported, not used for the criteria.
  Files (in `out`): `runs.csv` (one row per run: experiment arm, set, seed, winner, known
  best, converged, convergence step, steps run, test accuracy and regret, migrations,
  clones, deaths, wall ms, convergence events, events run), a population chart per run of the first seed
  (`population_<arm>_<set>.svg` and `.csv`: live iPkts per solution per step, the learning
  curve), box plots per arm for the multi-seed experiments (`steps.svg`: convergence
  steps; `events.svg`, `test_accuracy.svg`, `migrations.svg`), `summary.json` and
  `summary.md`.

  The runs go through `TartarusEmu.Sweep`: an arm is `"<arm> <set>"` (e.g. `"sharing p2"`),
  the seeds are `seed..seed + seeds - 1`, runs go in parallel on the schedulers (one at a
  time with a dashboard or in peer mode; the numbers are the same either way), and the
  summary gets the sweep's `sweep` key: per arm `steps`, `events`, `test_accuracy`,
  `migrations` (n, mean, sd, median, quartiles, IQR, min, max) and, for `sharing` and
  `danger`, one-sided Mann-Whitney tests that sharing (danger signals) converges in fewer
  steps than the arm without.
  """

  alias Tartarus.Clock
  alias TartarusEmu.{Scenario, Sweep}
  alias TartarusImmune.{Experiment, Sorting}
  alias TartarusImmune.Select.{Fig64b, Fig68, Lspan, Secondary}
  alias TartarusTools.{Report, Series, Stats, SVG}

  @experiments [
    :table6_2,
    :sharing,
    :danger,
    :fig6_8,
    :otfp,
    :nodes50,
    :dynamic,
    :influx,
    :barrage,
    :iot,
    :fig6_4b,
    :secondary,
    :lspan
  ]

  @schema [
    experiment: [type: {:in, @experiments}, default: :table6_2, doc: "which experiment"],
    seed: [type: :integer, default: 1, doc: "first seed"],
    seeds: [type: :pos_integer, default: 1, doc: "seeds per arm (seed, seed + 1, ...)"],
    nodes: [type: :pos_integer, doc: "hosts (default 10; 50 for nodes50, dynamic, iot, fig6_8)"],
    topology: [type: {:in, [:grid, :ring, :line]}, default: :grid, doc: "topology"],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "virtual hosts or peers"],
    group: [type: :pos_integer, default: 1, doc: "hosts per BEAM node in peer mode"],
    set: [
      type: :atom,
      doc:
        "data set of sharing/danger/otfp/influx/barrage/fig6_8 (default p2; otfp p1; fig6_8 p4)"
    ],
    steps: [
      type: :pos_integer,
      doc: "step limit per run (default 600; fig6_4b 300, secondary 120)"
    ],
    share: [type: {:range, 0, 1}, default: 0.9, doc: "convergence: leader's least share"],
    hold: [type: :pos_integer, default: 30, doc: "convergence: steps held"],
    eta: [type: :probability, default: 0.5, doc: "influx rate"],
    beta: [type: :pos_integer, doc: "barrage size (default 5; fig6_8 10)"],
    cost: [
      type: {:in, [:ops, :comparisons]},
      default: :ops,
      doc:
        "a sorting solution's cost: comparisons + moves (`ops`), or, as a labelled sensitivity run, comparisons alone (`TartarusImmune.Sorting.Comparisons`; the arms' names say so)"
    ],
    period: [type: :pos_integer, default: 10, doc: "steps between barrages"],
    ps: [
      type: {:list, :probability},
      default: [0.0, 0.1, 0.3, 0.5, 0.7, 1.0],
      doc: "dynamic sweep"
    ],
    etas: [type: {:list, :probability}, default: [0.1, 0.3, 0.5, 0.7, 0.9], doc: "influx sweep"],
    betas: [type: {:list, :pos_integer}, default: [1, 2, 5, 10, 20], doc: "barrage sweep"],
    add_at: [
      type: {:list, :pos_integer},
      default: [40, 80, 120, 160],
      doc: "otfp, fig6_4b: steps of the additions"
    ],
    repeat_at: [
      type: :pos_integer,
      default: 61,
      doc: "secondary: the round of the copy of the first barrage"
    ],
    out: [
      type: :any,
      doc: "output directory (default results/select-<experiment>-<time>), false for none"
    ],
    quiet: [type: :boolean, default: false, doc: "no progress lines"],
    dashboard: [
      type: :any,
      default: nil,
      doc:
        "serve the web dashboard on this port (127.0.0.1) while the runs go, or dashboard options (`port:`, `token:`, ...): the network of the run going now and the immune panel (`TartarusImmune.Panel`)"
    ]
  ]

  @csv_header ~w(arm set seed winner known_best converged convergence_step steps_run test_accuracy test_regret test_regret_rel migrations failed_moves clones deaths run_ms convergence_events events_run)

  @doc "The option schema."
  def schema, do: @schema

  @doc "Validates options."
  @spec validate(keyword()) :: {:ok, keyword()} | {:error, String.t()}
  def validate(opts), do: Tartarus.Options.validate(opts, @schema, "TartarusImmune.Select")

  @doc """
  Runs an experiment (options: `schema/0`). Returns `{:ok, %{summary:, out:, runs:}}`.
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts) do
    with {:ok, o} <- validate(opts) do
      o = Map.new(o)
      exp = o.experiment

      out =
        case Map.get(o, :out) do
          false -> false
          nil -> Report.default_out_dir("select-#{exp}")
          dir -> dir
        end

      with {:ok, dash} <- dashboard(o.dashboard) do
        try do
          run_plan(exp, o, out, dash)
        after
          if dash, do: stop_dashboard(dash)
        end
      end
    end
  end

  # One dashboard for all the runs: it shows the run going now (TartarusImmune.Panel).
  defp dashboard(nil), do: {:ok, nil}

  defp dashboard(spec) do
    table = TartarusImmune.Panel.new()
    net = fn -> TartarusImmune.Panel.network(table) end

    case TartarusEmu.Dashboard.serve(net, spec, [{TartarusImmune.Panel, table}]) do
      {:ok, dash} ->
        {:ok, {dash, table}}

      error ->
        :ets.delete(table)
        error
    end
  end

  defp stop_dashboard({dash, table}) do
    TartarusDashboard.stop(dash)
    :ets.delete(table)
  end

  defp run_plan(exp, o, out, dash) do
    panel = if dash, do: elem(dash, 1)
    t0 = Clock.machine_time(:millisecond)
    # the memo of sorting costs outlives the runs (each runs in its own process)
    TartarusImmune.Cache.ensure()

    # the arms: the plan's first seed (every seed runs the same arms)
    arms =
      for {arm, set, seed, extra} <- plan(exp, o),
          seed == o.seed,
          do: {arm_name(arm, set, o), %{arm: arm, set: set, extra: extra}}

    # one run at a time when the runs share a dashboard or peer nodes
    concurrency = if dash || o.mode == :peer, do: 1, else: System.schedulers_online()

    spec = %{
      name: "select-#{exp}",
      title: "Immune selection: #{exp}",
      subtitle:
        "#{exp}, #{o[:nodes] || default_nodes(exp)} hosts (#{o.topology}), " <>
          "#{steps_limit(exp, o)} steps at most",
      arms: arms,
      seeds: seeds(o),
      run: &run_one(&1, &2, exp, o, panel, concurrency),
      metrics:
        [
          {:steps, &steps/1, title(exp, :steps, o)},
          {:events, &events/1, title(exp, :events, o)},
          test_accuracy: :test_accuracy,
          migrations: :migrations
        ] ++ metrics(exp, o),
      tests: tests(exp, o),
      csv: {@csv_header, &csv_rows/1},
      concurrency: concurrency,
      summary: fn r ->
        exp
        |> summarize(runs(r), o)
        |> Map.merge(prereg(exp, r, o))
        |> Map.merge(%{
          experiment: to_string(exp),
          wall_ms: Clock.machine_time(:millisecond) - t0
        })
      end,
      write: fn dir, r -> write_populations(dir, runs(r), o) ++ figure(exp, dir, runs(r), o) end
    }

    {:ok, r} = Sweep.run(spec, out: out, quiet: o.quiet)
    {:ok, %{summary: r.summary, out: r.out, runs: runs(r)}}
  end

  defp run_one(arm, seed, exp, o, panel, concurrency) do
    %{arm: name, set: set, extra: extra} = arm.opts

    base = [
      set: set,
      seed: seed,
      steps: steps_limit(exp, o),
      nodes: extra[:nodes] || o[:nodes] || default_nodes(exp),
      topology: o.topology,
      mode: o.mode,
      group: o.group,
      share: o.share,
      hold: o.hold,
      eta: o.eta,
      beta: beta(exp, o),
      period: o.period,
      domain: domain(o.cost),
      out: false,
      # one progress line at a time
      quiet: o.quiet or concurrency > 1,
      panel: panel,
      label: "#{exp}: #{name}, #{set}, seed #{seed}"
    ]

    {:ok, r} = Scenario.run(Experiment, Keyword.merge(base, Keyword.delete(extra, :nodes)))
    {measure(exp, r, o), r.series}
  end

  # the pre-registered experiments' per-run measures, in the run's summary
  defp measure(:secondary, r, o),
    do:
      Map.put(
        r.summary,
        :secondary,
        Secondary.measure(r.series, r.summary.initial_population, {1, o.repeat_at})
      )

  defp measure(:lspan, r, o),
    do: Map.put(r.summary, :reach_mean, Lspan.reach_mean(r.summary.reach, o.period))

  defp measure(_exp, r, _o), do: r.summary

  defp metrics(:secondary, _o),
    do: [
      {:suppression_first, &suppression(&1, 0),
       "Fig. 6.3a: rounds until the losers are halved, first barrage (not halved: none)"},
      {:suppression_second, &suppression(&1, 1),
       "Fig. 6.3a: rounds until the losers are halved, its copy (not halved: none)"}
    ]

  defp metrics(:lspan, o),
    do: [
      {:reach_mean, & &1.reach_mean,
       "Fig. 6.8 by l_span: mean rounds until a distressed host has an iPkt that recognizes its problems (censored: #{o.period}), per run"}
    ]

  defp metrics(_exp, _o), do: []

  defp suppression(s, i), do: Enum.at(s.secondary.suppression, i)

  defp steps_limit(exp, o), do: o[:steps] || default_steps(exp)

  defp default_steps(:fig6_4b), do: Fig64b.config()[:steps]
  defp default_steps(:secondary), do: Secondary.config()[:steps]
  defp default_steps(_), do: 600

  # the sweep's runs as this module's records
  defp runs(sweep),
    do:
      Enum.map(
        sweep.runs,
        &%{
          arm: &1.opts.arm,
          set: &1.opts.set,
          seed: &1.seed,
          summary: &1.summary,
          series: &1.data
        }
      )

  # the box plots' titles; fig6_8's say which figure and configuration they are
  defp title(:fig6_8, :steps, o),
    do: "Fig. 6.8 (pre-registered): convergence rounds per run, #{fig_setting(o)}"

  defp title(:fig6_8, :events, o),
    do:
      "Fig. 6.8 (pre-registered): log-server events (migrations + executions), #{fig_setting(o)}"

  defp title(:lspan, :steps, o),
    do:
      "Fig. 6.8 by l_span: convergence rounds per run, #{fig_setting(o)} (not converged: #{steps_limit(:lspan, o)})"

  defp title(_, :steps, _o), do: "convergence step per run (not converged: the step limit)"
  defp title(_, :events, _o), do: "convergence in log-server events per run"

  defp fig_setting(o),
    do:
      "#{o[:set] || :p4}, #{o[:nodes] || 50} hosts, β #{beta(:fig6_8, o)}, not converged: #{steps_limit(:fig6_8, o)}"

  # an arm's name in the sweep: "<arm> <set>", labelled when the cost is not the default
  defp arm_name(arm, set, %{cost: :comparisons}), do: "#{arm} #{set} (comparisons)"
  defp arm_name(arm, set, _o), do: "#{arm} #{set}"

  defp domain(:ops), do: Sorting
  defp domain(:comparisons), do: Sorting.Comparisons

  # one-sided tests of the figures' claims: sharing and danger signals converge sooner
  defp tests(:sharing, o) do
    set = o[:set] || :p2
    [{arm_name("sharing", set, o), :less, arm_name("no_sharing", set, o), :steps}]
  end

  defp tests(exp, o) when exp in [:danger, :fig6_8] do
    set = o[:set] || default_set(exp)
    [d, nd, ns] = Enum.map(~w(danger no_danger no_sharing), &arm_name(&1, set, o))

    [
      {d, :less, nd, :steps},
      {d, :less, ns, :steps},
      {d, :less, nd, :events}
    ]
  end

  defp tests(:lspan, o) do
    set = o[:set] || :p4
    [l2, l3, l4, nd] = Enum.map(Lspan.arms(), &arm_name(elem(&1, 0), set, o))

    [
      {l4, :less, l2, :reach_mean},
      {l3, :less, l2, :reach_mean},
      {l2, :less, nd, :reach_mean},
      {l4, :less, l2, :steps},
      {l2, :less, nd, :steps}
    ]
  end

  defp tests(_, _), do: []

  defp default_nodes(e) when e in [:nodes50, :iot, :dynamic, :fig6_8, :lspan], do: 50
  defp default_nodes(_), do: 10

  defp default_set(e) when e in [:fig6_8, :lspan, :fig6_4b], do: :p4
  defp default_set(:secondary), do: :p1
  defp default_set(_), do: :p2

  defp beta(exp, o),
    do: o[:beta] || if(exp in [:fig6_8, :lspan], do: Fig68.config()[:beta], else: 5)

  defp seeds(o), do: Enum.map(0..(o.seeds - 1), &(o.seed + &1))

  defp plan(:table6_2, o),
    do: for(seed <- seeds(o), set <- [:p1, :p2, :p3, :p4], do: {"main", set, seed, []})

  defp plan(:sharing, o) do
    set = o[:set] || :p2

    for seed <- seeds(o),
        {arm, sh} <- [{"sharing", true}, {"no_sharing", false}],
        do: {arm, set, seed, [sharing: sh]}
  end

  defp plan(:danger, o) do
    set = o[:set] || :p2

    for seed <- seeds(o),
        {arm, x} <- [
          {"danger", [danger: true]},
          {"no_danger", [danger: false]},
          {"no_sharing", [sharing: false]}
        ],
        do: {arm, set, seed, x}
  end

  defp plan(:fig6_8, o) do
    set = o[:set] || :p4
    c = Fig68.config()
    fixed = [seed_hosts: c[:seed_hosts], per_node: c[:per_node], params: c[:params]]
    for seed <- seeds(o), {arm, x} <- Fig68.arms(), do: {arm, set, seed, x ++ fixed}
  end

  defp plan(exp, o) when exp in [:otfp, :fig6_4b] do
    set = o[:set] || if(exp == :otfp, do: :p1, else: :p4)
    alias Sorting.{Heap, Insertion, Merge, Quick, Selection, Shell}
    adds = Enum.zip(o.add_at, [Quick, Insertion, Merge, Heap])
    x = [solutions: [Shell, Selection], add: adds, stop: false]
    for seed <- seeds(o), do: {to_string(exp), set, seed, x}
  end

  defp plan(:secondary, o) do
    set = o[:set] || :p1
    x = [barrages: [1], repeat: [{o.repeat_at, 1}], stop: false]
    for seed <- seeds(o), do: {"secondary", set, seed, x}
  end

  defp plan(:lspan, o) do
    set = o[:set] || :p4
    c = Fig68.config()
    fixed = [seed_hosts: c[:seed_hosts], per_node: c[:per_node], reach: true]
    for seed <- seeds(o), {arm, x} <- Lspan.arms(), do: {arm, set, seed, x ++ fixed}
  end

  defp plan(:nodes50, o),
    do: for(seed <- seeds(o), set <- [:p2, :p3], do: {"nodes#{o[:nodes] || 50}", set, seed, []})

  defp plan(:dynamic, o) do
    set = o[:set] || :p4
    for seed <- seeds(o), p <- o.ps, do: {"p_#{p}", set, seed, [dynamic: p * 1.0]}
  end

  defp plan(:influx, o) do
    set = o[:set] || :p2
    for seed <- seeds(o), eta <- o.etas, do: {"eta_#{eta}", set, seed, [eta: eta * 1.0]}
  end

  defp plan(:barrage, o) do
    set = o[:set] || :p2
    for seed <- seeds(o), beta <- o.betas, do: {"beta_#{beta}", set, seed, [beta: beta]}
  end

  defp plan(:iot, o), do: for(seed <- seeds(o), do: {"iot", :temp, seed, []})

  # -- summaries ------------------------------------------------------------------------

  defp per_set(runs, key),
    do:
      runs
      |> Enum.group_by(&to_string(&1.set))
      |> Map.new(fn {s, rs} -> {s, Enum.map(rs, &get_in(&1, [:summary, key]))} end)

  defp steps_of(r), do: steps(r.summary)
  defp steps(s), do: s.convergence_step || s.steps_run

  # the same convergence in the second unit, a log server's count of events (sharing and
  # executions, `TartarusImmune.Experiment`); not converged: the count at the step limit
  defp events_of(r), do: events(r.summary)
  defp events(s), do: s.convergence_events || s.events_run
  defp events_all_of(r), do: r.summary.convergence_events_all || r.summary.events_all_run

  defp common(runs) do
    %{
      winners: runs |> per_set(:winner) |> Map.new(fn {s, ws} -> {s, majority(ws)} end),
      winners_by_seed: per_set(runs, :winner),
      known_best: runs |> per_set(:known_best) |> Map.new(fn {s, ws} -> {s, majority(ws)} end),
      convergence_steps: per_set(runs, :convergence_step),
      convergence_events: per_set(runs, :convergence_events),
      test_accuracy:
        runs |> per_set(:test_accuracy) |> Map.new(fn {s, xs} -> {s, Stats.mean(xs)} end),
      test_regret:
        runs |> per_set(:test_regret) |> Map.new(fn {s, xs} -> {s, Stats.mean(xs)} end),
      test_regret_rel:
        runs |> per_set(:test_regret_rel) |> Map.new(fn {s, xs} -> {s, Stats.mean(xs)} end),
      seeds: runs |> Enum.map(& &1.seed) |> Enum.uniq(),
      nodes: hd(runs).summary.nodes,
      mode: to_string(hd(runs).summary.mode)
    }
  end

  defp majority(ws),
    do:
      ws
      |> Enum.frequencies()
      |> Enum.max_by(fn {w, n} -> {n, -Enum.find_index(ws, &(&1 == w))} end)
      |> elem(0)

  defp arms(runs) do
    runs
    |> Enum.group_by(& &1.arm)
    |> Map.new(fn {arm, rs} ->
      steps = Enum.map(rs, &steps_of/1)
      events = Enum.map(rs, &events_of/1)
      events_all = Enum.map(rs, &events_all_of/1)

      {arm,
       %{
         convergence_steps: Enum.map(rs, & &1.summary.convergence_step),
         steps_mean: Stats.mean(steps),
         steps_sd: Stats.sd(steps),
         convergence_events: Enum.map(rs, & &1.summary.convergence_events),
         events_mean: Stats.mean(events),
         events_sd: Stats.sd(events),
         events_all_mean: Stats.mean(events_all),
         events_all_sd: Stats.sd(events_all),
         converged: Enum.count(rs, & &1.summary.converged),
         runs: length(rs),
         winners: Enum.map(rs, & &1.summary.winner),
         test_accuracy: Stats.mean(Enum.map(rs, & &1.summary.test_accuracy)),
         test_regret: Stats.mean(Enum.map(rs, & &1.summary.test_regret)),
         migrations_mean: Stats.mean(Enum.map(rs, & &1.summary.migrations)),
         failed_moves: Enum.map(rs, & &1.summary.failed_moves),
         wall_ms_mean: Stats.mean(Enum.map(rs, & &1.summary.run_ms))
       }}
    end)
  end

  defp summarize(:table6_2, runs, _o) do
    thesis = %{"p1" => "IS", "p2" => "QS", "p3" => "IS", "p4" => "QS"}
    by_seed = Enum.group_by(runs, & &1.seed)

    matches =
      Enum.count(by_seed, fn {_seed, rs} ->
        Enum.all?(rs, &(&1.summary.winner == thesis[to_string(&1.set)]))
      end)

    common(runs)
    |> Map.merge(%{
      thesis_best: thesis,
      seeds_matching_thesis: matches,
      seeds_matching_known_best:
        Enum.count(by_seed, fn {_seed, rs} ->
          Enum.all?(rs, &(&1.summary.winner == &1.summary.known_best))
        end)
    })
  end

  defp summarize(exp, runs, _o) when exp in [:otfp, :fig6_4b] do
    common(runs)
    |> Map.merge(%{
      final_population: Enum.map(runs, & &1.summary.population),
      convergences: Enum.map(runs, & &1.summary.convergences),
      arms: arms(runs)
    })
  end

  defp summarize(_exp, runs, _o) do
    a = arms(runs)

    common(runs)
    |> Map.merge(%{
      arms: a,
      convergence_steps: Map.new(a, fn {arm, x} -> {arm, x.convergence_steps} end),
      wall_ms_per_run: Map.new(a, fn {arm, x} -> {arm, x.wall_ms_mean} end)
    })
  end

  # The pre-registered experiment's own keys: how the run differs from the pre-registration
  # (nothing, for the measured run), per arm the rounds and events described, the guard and
  # the verdict (`TartarusImmune.Select.Fig68`).
  defp prereg(:fig6_8, r, o) do
    set = o[:set] || :p4
    [d, nd, ns] = Enum.map(~w(danger no_danger no_sharing), &arm_name(&1, set, o))
    agg = r.aggregates
    rounds = fn arm -> for run <- r.runs, run.arm == arm, do: steps(run.summary) end
    guard = Fig68.guard(rounds.(d), rounds.(nd), o.period)

    p =
      Enum.find_value(r.tests, fn t ->
        if {t.a, t.b, t.metric} == {d, nd, :steps}, do: t.p_value
      end)

    p_events =
      Enum.find_value(r.tests, fn t ->
        if {t.a, t.b, t.metric} == {d, nd, :events}, do: t.p_value
      end)

    c = Fig68.config()

    effective =
      Map.merge(
        Map.new(Keyword.take(Map.to_list(o), [:topology, :eta, :period, :share, :hold])),
        %{
          steps: steps_limit(:fig6_8, o),
          set: set,
          nodes: o[:nodes] || 50,
          beta: beta(:fig6_8, o),
          seed_hosts: c[:seed_hosts],
          per_node: c[:per_node],
          params: c[:params]
        }
      )

    deviations =
      Fig68.deviations(effective, seeds(o)) ++ if(o.cost == :ops, do: [], else: [:cost])

    verdict =
      Fig68.verdict(
        danger: agg[d].steps,
        no_danger: agg[nd].steps,
        no_sharing: agg[ns].steps,
        p_value: p,
        guard: guard
      )

    per_arm =
      Map.new([{"danger", d}, {"no_danger", nd}, {"no_sharing", ns}], fn {k, a} ->
        {k, %{rounds: agg[a].steps, events: agg[a].events}}
      end)

    %{
      preregistered: %{
        date: "2026-11-27",
        deviations: deviations,
        as_preregistered: deviations == [],
        per_arm: per_arm,
        p_signals_less_rounds: p,
        p_signals_less_events: p_events,
        guard:
          Map.update!(guard, :rounds, &Tuple.to_list/1)
          |> Map.update!(:at_first, &Tuple.to_list/1)
          |> Map.update!(:runs, &Tuple.to_list/1),
        verdict: verdict.outcome,
        criteria: verdict.criteria
      }
    }
  end

  defp prereg(:fig6_4b, r, o) do
    v = Fig64b.verdict(Enum.map(r.runs, & &1.summary.population))
    %{preregistered: Map.merge(v, %{date: "2026-12-06", deviations: deviations(:fig6_4b, o)})}
  end

  defp prereg(:secondary, r, o) do
    v = Secondary.verdict(Enum.map(r.runs, & &1.summary.secondary))
    %{preregistered: Map.merge(v, %{date: "2026-12-06", deviations: deviations(:secondary, o)})}
  end

  defp prereg(:lspan, r, o) do
    set = o[:set] || :p4
    [l2, l3, l4, nd] = names = Enum.map(Lspan.arms(), &arm_name(elem(&1, 0), set, o))

    p = fn a, b, m ->
      Enum.find_value(r.tests, fn t -> if {t.a, t.b, t.metric} == {a, b, m}, do: t.p_value end)
    end

    keyed = Enum.zip(Enum.map(Lspan.arms(), &elem(&1, 0)), names)

    reach =
      Map.new(keyed, fn {k, a} ->
        {k, for(run <- r.runs, run.arm == a, do: run.summary.reach_mean)}
      end)

    pooled =
      Map.new(keyed, fn {k, a} ->
        rs = for run <- r.runs, run.arm == a, do: run.summary.reach
        ts = Enum.flat_map(rs, & &1.times)
        cs = Enum.flat_map(rs, & &1.censored)

        {k,
         %{
           served: Stats.describe(ts),
           censored: length(cs),
           at_barrage: Enum.count(ts, &(&1 == 0)),
           hosts: length(ts) + length(cs)
         }}
      end)

    v = Lspan.verdict(reach, p.(l4, l2, :reach_mean), p.(l2, nd, :reach_mean))

    %{
      preregistered:
        Map.merge(v, %{
          date: "2026-12-06",
          deviations: deviations(:lspan, o),
          p_reach_4_less_2: p.(l4, l2, :reach_mean),
          p_reach_3_less_2: p.(l3, l2, :reach_mean),
          p_reach_2_less_none: p.(l2, nd, :reach_mean),
          p_rounds_4_less_2: p.(l4, l2, :steps),
          p_rounds_2_less_none: p.(l2, nd, :steps),
          reach_pooled: pooled,
          rounds: Map.new(keyed, fn {k, a} -> {k, r.aggregates[a].steps} end)
        })
    }
  end

  defp prereg(_exp, _r, _o), do: %{}

  # How a pre-registered run differs from its pre-registration: the options given that
  # change the configuration, and the seeds.
  defp deviations(exp, o) do
    {module, keys} =
      case exp do
        :fig6_4b -> {Fig64b, [:set, :nodes, :topology, :eta, :beta, :period, :steps, :add_at]}
        :secondary -> {Secondary, [:set, :nodes, :topology, :eta, :beta, :period, :steps]}
        :lspan -> {Lspan, [:set, :nodes, :topology, :eta, :beta, :period, :steps]}
      end

    eff = %{
      set: o[:set] || default_set(exp),
      nodes: o[:nodes] || default_nodes(exp),
      topology: o.topology,
      eta: o.eta,
      beta: beta(exp, o),
      period: o.period,
      steps: steps_limit(exp, o),
      add_at: o.add_at
    }

    reference =
      case exp do
        :lspan -> Map.new(Fig68.config())
        _ -> Map.new(module.config())
      end

    changed = for k <- keys, Map.has_key?(reference, k), reference[k] != eff[k], do: k

    changed =
      if exp == :secondary and o.repeat_at != 61, do: changed ++ [:repeat_at], else: changed

    changed = if o.cost != :ops, do: changed ++ [:cost], else: changed
    if seeds(o) == Enum.to_list(module.seeds()), do: changed, else: changed ++ [:seeds]
  end

  # -- files ----------------------------------------------------------------------------

  defp csv_rows(run) do
    %{arm: arm, set: set} = run.opts
    s = run.summary

    [
      [arm, set, run.seed, s.winner, s.known_best, s.converged, s.convergence_step, s.steps_run] ++
        [
          s.test_accuracy,
          s.test_regret,
          s.test_regret_rel,
          s.migrations,
          s.failed_moves,
          s.clones,
          s.deaths,
          s.run_ms,
          s.convergence_events,
          s.events_run
        ]
    ]
  end

  defp write_populations(dir, runs, o) do
    for r <- runs, r.seed == o.seed do
      name = "population_#{r.arm}_#{r.set}"
      chart = r.series |> Series.to_chart() |> Enum.reject(&(&1.name == "total"))

      svg =
        SVG.write!(
          Path.join(dir, name <> ".svg"),
          SVG.line_chart(chart,
            title:
              "live iPkts per solution, #{r.arm}, #{r.set}, seed #{r.seed}" <>
                conv_note(r.summary),
            x_label: "step",
            y_label: "iPkts"
          )
        )

      [svg, Report.write_csv!(dir, name, Series.header(r.series), Series.to_rows(r.series))]
    end
    |> List.flatten()
  end

  # Figs. 6.4b and 6.3a as the thesis draws them, population curves: here the mean over
  # the seeds of the live iPkts per solution per round, with 95 % intervals
  defp figure(exp, dir, runs, o) when exp in [:fig6_4b, :secondary] do
    names =
      runs
      |> Enum.flat_map(&Series.names(&1.series))
      |> Enum.map(&to_string/1)
      |> Enum.uniq()
      |> Enum.reject(&(&1 == "total"))
      |> Enum.sort()

    chart =
      Enum.map(names, fn name ->
        by_step =
          runs
          |> Enum.flat_map(&Series.points(&1.series, name))
          |> Enum.group_by(&elem(&1, 0), &elem(&1, 1))
          |> Enum.sort()

        # error bars every 10 rounds only: a bar per round would bury the curves
        m = SVG.mean_series(name, by_step)
        %{m | intervals: Enum.filter(m.intervals, fn {x, _, _} -> rem(x, 10) == 0 end)}
      end)

    n = length(runs)

    {title, marks} =
      case exp do
        :fig6_4b ->
          {"Fig. 6.4b (pre-registered): live iPkts per solution, #{o[:set] || :p4}, " <>
             "additions at #{Enum.join(o.add_at, ", ")}",
           "Shell and Selection at the start; Quick, Insertion, Merge, Heap added"}

        :secondary ->
          {"Fig. 6.3a's secondary response (pre-registered): live iPkts per solution, " <>
             "#{o[:set] || :p1}", "one barrage at round 1, its copy at round #{o.repeat_at}"}
      end

    svg =
      SVG.line_chart(chart,
        title: title,
        subtitle:
          "#{marks}; #{o[:nodes] || default_nodes(exp)} hosts, mean of #{n} seeds " <>
            "(#{o.seed}-#{o.seed + o.seeds - 1})",
        note: SVG.ci_note([n], "seeds", "lines") <> ", every 10 rounds",
        x_label: "round",
        y_label: "live iPkts",
        markers: false
      )

    [SVG.write!(Path.join(dir, "#{exp}.svg"), svg) | suppression_figure(exp, dir, runs)]
  end

  defp figure(_exp, _dir, _runs, _o), do: []

  # the secondary response's two times side by side (runs where the losers were not
  # halved within the phase are counted in the labels, not drawn)
  defp suppression_figure(:secondary, dir, runs) do
    groups =
      for {label, i} <- [{"first barrage", 0}, {"its copy", 1}] do
        ts = Enum.map(runs, &Enum.at(&1.summary.secondary.suppression, i))
        halved = Enum.reject(ts, &is_nil/1)
        {"#{label} (not halved: #{length(ts) - length(halved)})", halved}
      end

    svg =
      SVG.box_plot(groups,
        title: "Fig. 6.3a's secondary response: rounds until the losers are halved",
        subtitle: "P1, the losers: all but the leader at the copy; #{length(runs)} runs",
        y_label: "rounds"
      )

    [SVG.write!(Path.join(dir, "secondary_suppression.svg"), svg)]
  end

  defp suppression_figure(_exp, _dir, _runs), do: []

  defp conv_note(%{convergence_step: nil}), do: " (not converged)"
  defp conv_note(%{convergence_step: k, winner: w}), do: " (converged at #{k}: #{w})"
end
