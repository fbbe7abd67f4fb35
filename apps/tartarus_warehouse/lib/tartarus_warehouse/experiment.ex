defmodule TartarusWarehouse.Experiment do
  @moduledoc """
  The experiments of `mix tartarus.warehouse` (thesis §4.7), as one
  `TartarusEmu.Scenario`: each step is one configuration, run on a fresh emulated floor
  (`TartarusWarehouse.Floor`) and checked (`TartarusWarehouse.Checker`).

    * `:robots` - step k runs the thesis's warehouse jobs (T1-T4, §4.7.4) on k robots
      (k = 1..`robots`): `jobs` jobs with variable durations (each robot has its own pace
      and each execution a spread of `jitter`): a Gantt chart per k (Figs. 4.7-4.10) and
      the speed-up over one robot; then `equal_jobs` jobs with equal durations: the
      speed-up of the pipeline in steady state;
    * `:scaling` - each job size n of `sizes` and each of `seeds` seeds runs
      `scaling_jobs` jobs of n soft tasks (Sort, Merge, Add, Sub, Div repeating, §4.7.2)
      with equal durations on a network of `nodes` nodes (`scaling_robots` robots (R),
      `phi_nodes` shared-resource nodes (Φ), the rest secondary (Σ)), with the central
      server and with task agents (searching blind, as in the thesis, and guided by signal
      fields; returning to the distributor after each block, or continuing to the next
      job's robot), every central process charged `service_ms` a message: the
      steady-state time per task against tasks per job (Fig. 4.4);
    * `:otfp` - on-the-fly programming (§4.5.4): 6 warehouse jobs on 3 robots, a task T2A
      (a detour, its program compiled at run time) added after T2 while job 2 runs T2,
      deleted, and added again (Fig. 4.12: a Gantt chart); then 16 jobs of 10 soft tasks
      on 4 robots while tasks are added (after 2, 4 and 6 jobs completed: 1, 1 and 3
      tasks) and deleted (3 tasks after 9 jobs): the tasks and the time per task of each
      job (Fig. 4.5);
    * `:removal` - 6 warehouse jobs on 3 robots; robot r2's battery runs low once 2 jobs
      completed (it finishes its job and leaves), and a fourth robot joins once 4 jobs
      completed (Fig. 4.13);
    * `:mixed` - 6 jobs on 4 robots: jobs 1 and 6 purely sequential, jobs 2-5 two
      independent sequences each (Fig. 4.11);
    * `:concurrent` - §4.5.5: m jobs of n independent tasks on n and 2n robots: the
      makespan against m·t, the most tasks at once (`TartarusWarehouse.Experiment.Concurrent`);
    * `:manet` - §4.3: jobs on a floor whose robots and Σ nodes leave the network and
      rejoin it while the jobs run (`TartarusWarehouse.Experiment.Manet`);
    * `:failover` - beyond the thesis: 10 warehouse jobs on 3 robots while the
      distributor's host is killed twice (100 ms and 50 ms down) and started again on its
      journal, for three seeds (seed, seed + 1, seed + 2): jobs lost, jobs duplicated (a
      task run twice), violations; and once without persistence, for contrast.

  Each experiment is a module (`TartarusWarehouse.Experiment.Robots`, `...Scaling`,
  `...Otfp`, `...Removal`, `...Mixed`, `...Failover`) that declares its points and the
  floors each point runs, and reads its series, charts and summary keys from the runs
  (the behaviour `TartarusWarehouse.Experiment.Kind`, with the helpers they share);
  `experiments/0` is the registry `mix tartarus.warehouse` reads. This module runs them
  (`TartarusWarehouse.Floor.run/1` on each declared floor) and is the scenario.

  Every run's mutual-exclusion violations (Eq. 4.1) and incomplete jobs are counted in
  the summary (`mutex_violations`, `deadlocks`: jobs not completed within `timeout_ms`).
  """
  @behaviour TartarusEmu.Scenario

  alias TartarusTools.{Report, Series}
  alias TartarusWarehouse.{Checker, Floor}

  alias TartarusWarehouse.Experiment.{
    Concurrent,
    Failover,
    Manet,
    Mixed,
    Otfp,
    Output,
    Removal,
    Robots,
    Scaling
  }

  @experiments [
    robots: Robots,
    scaling: Scaling,
    otfp: Otfp,
    removal: Removal,
    mixed: Mixed,
    failover: Failover,
    concurrent: Concurrent,
    manet: Manet
  ]

  @schema [
    experiment: [
      type: {:in, Keyword.keys(@experiments)},
      default: :robots,
      doc: "which experiment"
    ],
    seed: [type: :integer, default: 1, doc: "seed"],
    out: [
      type: :any,
      doc: "output directory (default `results/warehouse-<experiment>-<UTC timestamp>`), or false"
    ],
    quiet: [type: :boolean, default: false, doc: "no progress line"],
    dashboard: [
      type: :any,
      doc:
        "serve the web dashboard on this port (127.0.0.1) while the experiment runs, or dashboard options (`port:`, `token:`, ... of `TartarusDashboard`): the graph of the floor running now and the warehouse panel (`TartarusWarehouse.Panel`)"
    ],
    scale: [
      type: {:or, [{:in, [nil]}, {:range, 1.0e-4, 1000}]},
      expected: "a number from 0.0001 to 1000",
      default: nil,
      doc:
        "time scale: 0.01 runs a 2 s task as 20 ms (default: 0.1 for `scaling`, 0.01 for the others)"
    ],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    time: [
      type: {:in, [:real, :virtual]},
      default: :real,
      doc:
        "the floors' clock: `real`, or `virtual` (`Tartarus.Clock.Virtual`, seeded with " <>
          "the seed: task durations, service times and link latencies are the only time, " <>
          "CPU is none; with `mode: :virtual` only)"
    ],
    robots: [type: :pos_integer, default: 4, doc: "`robots`: up to this many robots"],
    jobs: [type: :pos_integer, default: 4, doc: "`robots`: jobs with variable durations"],
    jitter: [
      type: {:range, 0, 0.95},
      default: 0.3,
      doc: "`robots`: spread of each execution's duration (a factor in 1 ± jitter)"
    ],
    equal_jobs: [type: :pos_integer, default: 40, doc: "`robots`: jobs with equal durations"],
    sizes: [
      type: {:list, :pos_integer},
      default: [5, 10, 20, 30, 45, 60],
      doc: "`scaling`: the tasks per job of its points"
    ],
    scaling_jobs: [
      type: {:custom, &TartarusWarehouse.Experiment.jobs_spec?/1},
      default: 120,
      doc:
        "`scaling`: jobs per run: a positive integer, or `{:per_size, a, b}` for a·n + b jobs at n tasks per job (the flag's `2n+20`)"
    ],
    nodes: [type: :pos_integer, default: 100, doc: "`scaling`: network nodes"],
    scaling_robots: [type: :pos_integer, default: 60, doc: "`scaling`: robots among them"],
    phi_nodes: [
      type: :non_neg_integer,
      default: 20,
      doc: "`scaling`: shared-resource (Φ) nodes among them (the rest but `jd` are Σ nodes)"
    ],
    phi_agents: [
      type: :boolean,
      default: false,
      doc:
        "`scaling`: each Φ node runs a rack, the static agent that receives the task code from the task agents before their robot runs it (§4.7.1, `TartarusWarehouse.Rack`; the agents' designs only)"
    ],
    seeds: [
      type: :pos_integer,
      default: 3,
      doc:
        "`scaling`, `removal`, `mixed`, `concurrent`, `manet`: seeds per point (seed, seed + 1, ...); medians over them"
    ],
    drop: [
      type: :non_neg_integer,
      default: 10,
      doc: "`scaling`: the first and the last this many jobs are left out of the metric"
    ],
    designs: [
      type: {:list, {:in, [:central, :agents, :agents_continue, :guided, :guided_continue]}},
      default: [:central, :agents, :agents_continue, :guided, :guided_continue],
      doc:
        "`scaling`: the floors of each point: `central`, the blind task agents returning to the distributor after each block (`agents`) or continuing to the next job's robot (`agents_continue`), the guided agents likewise (`guided`, `guided_continue`)"
    ],
    latency_ms: [
      type: :non_neg_integer,
      default: 0,
      doc:
        "`scaling`, `removal`, `mixed`, `concurrent`, `manet`: one-way delay of every link, paid alike by the central server's messages and the agents' hand-offs (see `TartarusWarehouse.Floor`)"
    ],
    service_ms: [
      type: {:range, 0, 60_000},
      default: 2.2,
      doc:
        "`scaling`, `concurrent`: the time (ms) the central server and the Job Distributor each take for every message they handle (see `TartarusWarehouse.Service`); 0: a BEAM process's microseconds"
    ],
    big_robots: [
      type: :non_neg_integer,
      default: 0,
      doc:
        "`scaling`: also one run on this many robots (e.g. 1000; 0: none): 20 jobs of 5 soft tasks in 20 independent pipelines, agents guided by signal fields"
    ],
    conc_tasks: [
      type: {:list, :pos_integer},
      default: [2, 4],
      doc: "`concurrent`: the independent tasks per job n of its arms (each on n and 2n robots)"
    ],
    conc_jobs: [type: :pos_integer, default: 5, doc: "`concurrent`: jobs per floor (m)"],
    churn: [
      type: {:list, :probability},
      default: [0.0, 0.1],
      doc:
        "`manet`: the arms' probability that a node (robot or Σ) up leaves the network in a tick (a quarter of a task)"
    ],
    manet_robots: [type: :pos_integer, default: 4, doc: "`manet`: robots (and as many Σ nodes)"],
    manet_jobs: [type: :pos_integer, default: 8, doc: "`manet`: jobs per floor"],
    timeout_ms: [type: :pos_integer, default: 300_000, doc: "a run gives up after this long"]
  ]

  @doc false
  # Jobs per run of `scaling`: a count, or {:per_size, a, b} (a·n + b at n tasks per job).
  @spec jobs_spec?(term()) :: boolean()
  def jobs_spec?(n) when is_integer(n), do: n > 0

  def jobs_spec?({:per_size, a, b}) when is_integer(a) and is_integer(b),
    do: a >= 0 and b >= 0 and a + b > 0

  def jobs_spec?(_), do: false

  @doc """
  The registry: every experiment's name and module, in the order `mix tartarus.warehouse`
  lists them.

      iex> Keyword.keys(TartarusWarehouse.Experiment.experiments())
      [:robots, :scaling, :otfp, :removal, :mixed, :failover, :concurrent, :manet]
  """
  @spec experiments() :: [{atom(), module()}]
  def experiments, do: @experiments

  @doc """
  The module of the experiment `name`.

      iex> TartarusWarehouse.Experiment.module(:scaling)
      TartarusWarehouse.Experiment.Scaling
  """
  @spec module(atom()) :: module()
  def module(name), do: Keyword.fetch!(@experiments, name)

  @doc "The options of `run/1`."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Checks `run/1`'s options; returns them with defaults, or `{:error, message}`.

      iex> {:ok, opts} = TartarusWarehouse.Experiment.validate(experiment: :scaling)
      iex> {opts[:sizes], opts[:nodes], opts[:scale]}
      {[5, 10, 20, 30, 45, 60], 100, 0.1}
      iex> TartarusWarehouse.Experiment.validate(experiment: :nope)
      {:error, "invalid options given to TartarusWarehouse.Experiment.run/1 for key :experiment: expected one of [:robots, :scaling, :otfp, :removal, :mixed, :failover, :concurrent, :manet], got: :nope"}
  """
  @spec validate(keyword()) :: {:ok, keyword()} | {:error, String.t()}
  def validate(opts) do
    with {:ok, opts} <-
           Tartarus.Options.validate(opts, @schema, "TartarusWarehouse.Experiment.run/1") do
      need = opts[:scaling_robots] + opts[:phi_nodes] + 1

      cond do
        opts[:time] == :virtual and opts[:mode] == :peer ->
          {:error,
           "invalid options given to TartarusWarehouse.Experiment.run/1 for key :time: virtual time needs mode: :virtual (networks of real BEAM nodes run in real time), got: mode: :peer"}

        opts[:nodes] < need ->
          {:error,
           "invalid options given to TartarusWarehouse.Experiment.run/1 for key :nodes: expected at least scaling_robots + phi_nodes + 1 (#{need}), got: #{opts[:nodes]}"}

        opts[:phi_agents] and opts[:phi_nodes] == 0 ->
          {:error,
           "invalid options given to TartarusWarehouse.Experiment.run/1 for key :phi_agents: the racks run on the Φ nodes, and phi_nodes is 0"}

        opts[:scale] == nil ->
          {:ok, Keyword.put(opts, :scale, if(opts[:experiment] == :scaling, do: 0.1, else: 0.01))}

        true ->
          {:ok, opts}
      end
    end
  end

  @doc """
  Runs an experiment (options above) through `TartarusEmu.Scenario.run/2`. Returns
  `{:ok, %{summary:, series:, out:, files:}}` or `{:error, message}`.

  #{Tartarus.Options.docs(@schema)}
  """
  @spec run(keyword()) :: {:ok, TartarusEmu.Scenario.result()} | {:error, term()}
  def run(opts \\ []) do
    with {:ok, opts} <- validate(opts) do
      out =
        case Keyword.fetch(opts, :out) do
          {:ok, out} -> out
          :error -> Report.default_out_dir("warehouse-#{opts[:experiment]}")
        end

      points = module(opts[:experiment]).points(Map.new(opts))

      # One step: the sweep over the experiment's points (TartarusEmu.Sweep), whose
      # runs.csv and aggregates go to <out>/sweep.
      TartarusEmu.Scenario.run(__MODULE__,
        seed: opts[:seed],
        out: out,
        quiet: opts[:quiet],
        dashboard: opts[:dashboard],
        time: opts[:time],
        steps: 1,
        params: Keyword.drop(opts, [:seed, :out, :dashboard]),
        points: points,
        sweep_out: out && Path.join(out, "sweep")
      )
    end
  end

  # -- the scenario ------------------------------------------------------------------

  @impl TartarusEmu.Scenario
  def name, do: "warehouse"

  @impl TartarusEmu.Scenario
  def title, do: "Warehouse (thesis ch. 4): a clock-less pipeline of task agents"

  @impl TartarusEmu.Scenario
  def setup(opts) do
    {:ok,
     %{
       p: Map.new(opts.params),
       seed: opts.seed,
       points: opts.points,
       sweep_out: opts.sweep_out,
       sweep: nil,
       runs: [],
       series: Series.new(),
       # what the web dashboard shows (TartarusWarehouse.Panel)
       panel: TartarusWarehouse.Panel.new()
     }}
  end

  # The experiment's runs are a sweep (`TartarusEmu.Sweep`): its arms and seeds come from
  # the experiment (`c:sweep/1`: by default an arm a point, on the run's seed), one at a
  # time (floors are timed on the wall clock, and the dashboard shows one floor); each run
  # is a point's floors. The series are recorded point by point, in the sweep's order.
  @impl TartarusEmu.Scenario
  def step(state, 1) do
    module = module(state.p.experiment)
    plan = sweep_plan(module, state)

    spec = %{
      name: "warehouse-#{state.p.experiment}",
      title: "#{title()}: #{state.p.experiment}, the runs",
      arms: plan.arms,
      seeds: plan.seeds,
      order: :arm_major,
      concurrency: 1,
      run: fn arm, seed -> run_point(module, plan.point.(arm.opts, seed), state) end,
      metrics: metrics(module)
    }

    {:ok, sweep} = TartarusEmu.Sweep.run(spec, out: state.sweep_out, quiet: state.p.quiet)

    state =
      Enum.reduce(sweep.runs, state, fn %{data: {point, runs}}, state ->
        state = %{state | runs: state.runs ++ runs}
        %{state | series: module.record(point, state)}
      end)

    %{state | sweep: sweep.summary.sweep}
  end

  defp sweep_plan(module, state) do
    if function_exported?(module, :sweep, 1),
      do: module.sweep(state),
      else: %{
        arms: Enum.map(state.points, &{to_string(&1), &1}),
        seeds: [state.seed],
        point: fn point, _seed -> point end
      }
  end

  # A point's floors, in order; the sweep's summary of the run: its makespans by kind and
  # what every run checks.
  defp run_point(module, point, state) do
    TartarusWarehouse.Panel.point(state.panel, state.p.experiment, point)

    runs =
      for {kind, opts, extra} <- module.runs(point, state) do
        state
        |> floor!(opts)
        |> Map.merge(%{kind: kind, point: point, specs: opts[:jobs]})
        |> Map.merge(extra)
      end

    summary = %{
      makespan_ms: Map.new(runs, &{&1.kind, round(&1.makespan_ms)}),
      completed_jobs: runs |> Enum.map(& &1.completed_jobs) |> Enum.sum(),
      mutex_violations: runs |> Enum.map(& &1.violations) |> Enum.sum(),
      deadlocks: runs |> Enum.map(&length(&1.timed_out)) |> Enum.sum()
    }

    {summary, {point, runs}}
  end

  defp metrics(module) do
    makespans =
      for kind <- module.kinds(), do: {:"makespan_ms_#{kind}", &get_in(&1, [:makespan_ms, kind])}

    makespans ++
      [
        completed_jobs: :completed_jobs,
        mutex_violations: :mutex_violations,
        deadlocks: :deadlocks
      ]
  end

  @impl TartarusEmu.Scenario
  def done?(_state, _k), do: true

  @impl TartarusEmu.Scenario
  def network(state), do: fn -> TartarusWarehouse.Panel.network(state.panel) end

  @impl TartarusEmu.Scenario
  def panels(state), do: [{TartarusWarehouse.Panel, state.panel}]

  @impl TartarusEmu.Scenario
  def teardown(state), do: :ets.delete(state.panel)

  @impl TartarusEmu.Scenario
  def series(state), do: state.series

  defp floor!(state, opts) do
    {:ok, r} = run_floor(state, opts)
    c = Checker.completion(r.history, opts[:jobs])

    Map.merge(r, %{
      violations: length(Checker.violations(r.history)),
      completed_jobs: length(c.completed),
      occupancy: Checker.occupancy(r.history, r.t0_us, 20)
    })
  end

  # In virtual time each floor runs alone in a fresh VM, under a clock of its own seeded
  # with the floor's seed (TartarusEmu.FreshVM: a floor that shares a VM with earlier ones
  # does not replay exactly); the web dashboard then shows the points, not each floor's
  # robots. In real time, here, publishing to the dashboard's panel.
  defp run_floor(%{p: %{time: :virtual}}, opts) do
    seed = Keyword.get(opts, :seed, 1)

    TartarusEmu.FreshVM.run(
      fn -> Tartarus.Clock.Virtual.within(:virtual, seed, fn -> Floor.run(opts) end) end,
      apps: [:tartarus_warehouse]
    )
  end

  defp run_floor(state, opts), do: Floor.run(Keyword.put(opts, :status, state.panel))

  @impl TartarusEmu.Scenario
  def charts(state), do: module(state.p.experiment).charts(state)

  @impl TartarusEmu.Scenario
  def summary(state) do
    p = state.p
    runs = state.runs

    base = %{
      experiment: to_string(p.experiment),
      jobs: runs |> Enum.map(&length(&1.jobs)) |> Enum.sum(),
      tasks: runs |> Enum.map(&length(&1.history)) |> Enum.sum(),
      completed_jobs: runs |> Enum.map(& &1.completed_jobs) |> Enum.sum(),
      mutex_violations: runs |> Enum.map(& &1.violations) |> Enum.sum(),
      deadlocks: runs |> Enum.map(&length(&1.timed_out)) |> Enum.sum(),
      scale: p.scale,
      mode: to_string(p.mode),
      time: to_string(p.time),
      wall_ms: runs |> Enum.map(& &1.wall_ms) |> Enum.sum()
    }

    Map.put(module(p.experiment).summary(base, state), :sweep, state.sweep)
  end

  @impl TartarusEmu.Scenario
  def comparisons(state), do: module(state.p.experiment).comparisons(state)

  @impl TartarusEmu.Scenario
  def write(state, dir), do: Output.write(state, dir, module(state.p.experiment))
end
