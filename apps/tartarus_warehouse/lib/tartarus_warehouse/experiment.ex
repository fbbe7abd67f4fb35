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
    * `:scaling` - step i runs `scaling_jobs` jobs of n soft tasks (Sort, Merge, Add, Sub,
      Div repeating, §4.7.2; n = 5, 10, 20, ... up to `max_tasks`) with equal durations on
      a network of `nodes` nodes (`scaling_robots` robots, the rest secondary), with task
      agents (searching blind, as in the thesis, and guided by signal fields) and with
      the central server: the average time per task against tasks per job (Fig. 4.4);
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
    * `:failover` - beyond the thesis: 10 warehouse jobs on 3 robots while the
      distributor's host is killed twice (100 ms and 50 ms down) and started again on its
      journal, for three seeds (seed, seed + 1, seed + 2): jobs lost, jobs duplicated (a
      task run twice), violations; and once without persistence, for contrast.

  Every run's mutual-exclusion violations (Eq. 4.1) and incomplete jobs are counted in
  the summary (`mutex_violations`, `deadlocks`: jobs not completed within `timeout_ms`).
  """
  @behaviour TartarusEmu.Scenario

  alias TartarusTools.{Report, Series, SVG}
  alias TartarusWarehouse.{Checker, Floor}

  @schema [
    experiment: [
      type: {:in, [:robots, :scaling, :otfp, :removal, :mixed, :failover]},
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
        "serve the web dashboard on this port (127.0.0.1) while the experiment runs, or dashboard options (`port:`, `token:`, ... of `TartarusTools.Dashboard`): the graph of the floor running now and the warehouse panel (`TartarusWarehouse.Panel`)"
    ],
    scale: [type: :number, default: 0.01, doc: "time scale: 0.01 runs a 2 s task as 20 ms"],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    robots: [type: :pos_integer, default: 4, doc: "`robots`: up to this many robots"],
    jobs: [type: :pos_integer, default: 4, doc: "`robots`: jobs with variable durations"],
    jitter: [type: :number, default: 0.3, doc: "`robots`: spread of each execution's duration"],
    equal_jobs: [type: :pos_integer, default: 40, doc: "`robots`: jobs with equal durations"],
    max_tasks: [type: :pos_integer, default: 60, doc: "`scaling`: tasks per job up to this"],
    scaling_jobs: [type: :pos_integer, default: 5, doc: "`scaling`: jobs per run"],
    nodes: [type: :pos_integer, default: 100, doc: "`scaling`: network nodes"],
    scaling_robots: [type: :pos_integer, default: 10, doc: "`scaling`: robots among them"],
    latency_ms: [
      type: :non_neg_integer,
      default: 0,
      doc:
        "`scaling`: one-way delay of every link, paid alike by the central server's messages and the agents' hand-offs (see `TartarusWarehouse.Floor`)"
    ],
    server_ms: [
      type: :non_neg_integer,
      default: 0,
      doc:
        "`scaling`: the central server's time to handle one robot message (see `TartarusWarehouse.Central`, \"Service time\"); 0: a BEAM process's microseconds"
    ],
    big_robots: [
      type: :non_neg_integer,
      default: 0,
      doc:
        "`scaling`: also one run on this many robots (e.g. 1000; 0: none): 20 jobs of 5 soft tasks in 20 independent pipelines, agents guided by signal fields"
    ],
    timeout_ms: [type: :pos_integer, default: 300_000, doc: "a run gives up after this long"]
  ]

  @thesis_speedup %{2 => 1.75, 3 => 1.84, 4 => 2.21}

  @doc "The options of `run/1`."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Checks `run/1`'s options; returns them with defaults, or `{:error, message}`.

      iex> {:ok, opts} = TartarusWarehouse.Experiment.validate(experiment: :scaling)
      iex> {opts[:max_tasks], opts[:nodes]}
      {60, 100}
      iex> TartarusWarehouse.Experiment.validate(experiment: :nope)
      {:error, "invalid options given to TartarusWarehouse.Experiment.run/1 for key :experiment: expected one of [:robots, :scaling, :otfp, :removal, :mixed, :failover], got: :nope"}
  """
  @spec validate(keyword()) :: {:ok, keyword()} | {:error, String.t()}
  def validate(opts) do
    with {:ok, opts} <-
           Tartarus.Options.validate(opts, @schema, "TartarusWarehouse.Experiment.run/1") do
      if opts[:nodes] < opts[:scaling_robots] + 1,
        do:
          {:error,
           "invalid options given to TartarusWarehouse.Experiment.run/1 for key :nodes: expected at least scaling_robots + 1 (#{opts[:scaling_robots] + 1}), got: #{opts[:nodes]}"},
        else: {:ok, opts}
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

      points = points(opts)

      TartarusEmu.Scenario.run(__MODULE__,
        seed: opts[:seed],
        out: out,
        quiet: opts[:quiet],
        dashboard: opts[:dashboard],
        steps: length(points),
        params: Keyword.drop(opts, [:seed, :out, :quiet, :dashboard]),
        points: points
      )
    end
  end

  defp points(opts) do
    case opts[:experiment] do
      :robots -> Enum.to_list(1..opts[:robots])
      :scaling -> Enum.filter([5, 10, 20, 30, 40, 50, 60, 80, 100], &(&1 <= opts[:max_tasks]))
      :failover -> [1, 2, 3]
      _single -> [1]
    end
    |> case do
      [] -> [opts[:max_tasks]]
      list -> list
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
       runs: [],
       series: Series.new(),
       # what the web dashboard shows (TartarusWarehouse.Panel)
       panel: TartarusWarehouse.Panel.new()
     }}
  end

  @impl TartarusEmu.Scenario
  def step(state, k) do
    point = Enum.at(state.points, k - 1)
    TartarusWarehouse.Panel.point(state.panel, state.p.experiment, point)
    runs = run_point(state.p.experiment, point, state)
    state = %{state | runs: state.runs ++ runs}
    %{state | series: record(state.p.experiment, point, state)}
  end

  @impl TartarusEmu.Scenario
  def done?(state, k), do: k >= length(state.points)

  @impl TartarusEmu.Scenario
  def network(state), do: fn -> TartarusWarehouse.Panel.network(state.panel) end

  @impl TartarusEmu.Scenario
  def panels(state), do: [{TartarusWarehouse.Panel, state.panel}]

  @impl TartarusEmu.Scenario
  def teardown(state), do: :ets.delete(state.panel)

  @impl TartarusEmu.Scenario
  def series(state), do: state.series

  defp run_point(:robots, k, state) do
    p = state.p
    paces = Enum.map(1..k, &(1.0 + 0.1 * rem(&1 * 7, 5)))

    variable =
      floor!(
        state.panel,
        robots: k,
        jobs: thesis_jobs(p.jobs, 2000),
        scale: p.scale,
        jitter: p.jitter,
        paces: paces,
        seed: state.seed,
        mode: p.mode,
        timeout_ms: p.timeout_ms
      )

    equal =
      floor!(
        state.panel,
        robots: k,
        jobs: thesis_jobs(p.equal_jobs, 2000),
        scale: p.scale,
        seed: state.seed,
        mode: p.mode,
        timeout_ms: p.timeout_ms
      )

    [
      Map.merge(variable, %{kind: :variable, point: k, specs: thesis_jobs(p.jobs, 2000)}),
      Map.merge(equal, %{kind: :equal, point: k, specs: thesis_jobs(p.equal_jobs, 2000)})
    ]
  end

  defp run_point(:scaling, n, state) do
    p = state.p
    jobs = soft_jobs(p.scaling_jobs, n, 2000)

    big =
      if p.big_robots > 0 and n == List.last(state.points) do
        big_jobs =
          for j <- 1..20 do
            %{
              id: j,
              tasks:
                for {prog, i} <- Enum.with_index(TartarusWarehouse.Program.soft(5), 1) do
                  %{
                    name: "T#{i}",
                    resources: [{:psi, i, j}],
                    after: if(i > 1, do: ["T#{i - 1}"], else: []),
                    program: prog
                  }
                end
            }
          end

        r =
          floor!(
            state.panel,
            robots: p.big_robots,
            jobs: big_jobs,
            scale: p.scale,
            guide: true,
            seed: state.seed,
            mode: p.mode,
            timeout_ms: p.timeout_ms
          )

        [Map.merge(r, %{kind: :big, point: n, specs: big_jobs})]
      else
        []
      end

    big ++
      for kind <- [:agents, :central, :guided] do
        r =
          floor!(
            state.panel,
            robots: p.scaling_robots,
            secondary: p.nodes - p.scaling_robots - 1,
            jobs: jobs,
            scale: p.scale,
            design: if(kind == :central, do: :central, else: :agents),
            guide: kind == :guided,
            seed: state.seed,
            mode: p.mode,
            latency_ms: p.latency_ms,
            server_ms: p.server_ms,
            timeout_ms: p.timeout_ms
          )

        Map.merge(r, %{kind: kind, point: n, specs: jobs})
      end
  end

  defp run_point(:otfp, _, state) do
    p = state.p
    detour = detour_program()
    t = fn ms -> round(ms * p.scale / 0.01) end
    t2a = %{name: "T2A", resources: [:detour], program: detour, duration_ms: 1500}
    jobs = thesis_jobs(6, 2000)

    gantt =
      floor!(
        state.panel,
        robots: 3,
        jobs: jobs,
        resources: [:bay, :line, :rack, :wall, :packing, :return, :detour],
        scale: p.scale,
        jitter: p.jitter,
        seed: state.seed,
        mode: p.mode,
        timeout_ms: p.timeout_ms,
        events: [
          {{:ms, t.(45)}, {:insert, "T2", t2a}},
          {{:ms, t.(95)}, {:delete, "T2A"}},
          {{:ms, t.(135)}, {:insert, "T2", t2a}}
        ]
      )

    soft = soft_jobs(16, 10, 2000)

    extra = fn i ->
      %{name: "X#{i}", resources: [{:extra, i}], program: detour, duration_ms: 2000}
    end

    stream =
      floor!(
        state.panel,
        robots: 4,
        jobs: soft,
        resources: Enum.map(1..10, &{:psi, &1}) ++ Enum.map(1..5, &{:extra, &1}),
        scale: p.scale,
        seed: state.seed,
        mode: p.mode,
        timeout_ms: p.timeout_ms,
        events: [
          {2, {:insert, "T10", extra.(1)}},
          {4, {:insert, "T5", extra.(2)}},
          {6, {:insert, "T3", extra.(3)}},
          {6, {:insert, "T7", extra.(4)}},
          {6, {:insert, "T8", extra.(5)}},
          {9, {:delete, "X3"}},
          {9, {:delete, "X4"}},
          {9, {:delete, "X5"}}
        ]
      )

    [
      Map.merge(gantt, %{kind: :variable, point: 1, specs: jobs}),
      Map.merge(stream, %{kind: :stream, point: 1, specs: soft})
    ]
  end

  defp run_point(:removal, _, state) do
    p = state.p
    jobs = thesis_jobs(8, 2000)

    r =
      floor!(
        state.panel,
        robots: 4,
        standby: [4],
        jobs: jobs,
        scale: p.scale,
        jitter: p.jitter,
        seed: state.seed,
        mode: p.mode,
        timeout_ms: p.timeout_ms,
        events: [{2, {:retire, 2}}, {4, {:join, 4}}]
      )

    [Map.merge(r, %{kind: :variable, point: 1, specs: jobs})]
  end

  defp run_point(:mixed, _, state) do
    p = state.p
    jobs = mixed_jobs(6, 2000)

    r =
      floor!(
        state.panel,
        robots: 4,
        jobs: jobs,
        scale: p.scale,
        jitter: p.jitter,
        seed: state.seed,
        mode: p.mode,
        timeout_ms: p.timeout_ms
      )

    [Map.merge(r, %{kind: :variable, point: 1, specs: jobs})]
  end

  defp run_point(:failover, i, state) do
    p = state.p
    jobs = thesis_jobs(10, 2000)
    t = fn ms -> round(ms * p.scale / 0.01) end
    seed = state.seed + i - 1

    kills = [
      {{:ms, t.(40 + 20 * i)}, {:kill_distributor, t.(100)}},
      {{:ms, t.(240 + 20 * i)}, {:kill_distributor, t.(50)}}
    ]

    r =
      floor!(
        state.panel,
        robots: 3,
        jobs: jobs,
        scale: p.scale,
        jitter: p.jitter,
        seed: seed,
        mode: p.mode,
        timeout_ms: p.timeout_ms,
        failover: true,
        events: kills
      )

    runs = [Map.merge(r, %{kind: :variable, point: i, specs: jobs, run_seed: seed})]

    if i == 1 do
      # The same loss without persistence: the distributor and what it knew are gone.
      lost =
        floor!(
          state.panel,
          robots: 3,
          jobs: jobs,
          scale: p.scale,
          seed: seed,
          mode: p.mode,
          timeout_ms: t.(2000),
          events: [hd(kills)]
        )

      runs ++ [Map.merge(lost, %{kind: :no_persistence, point: i, specs: jobs, run_seed: seed})]
    else
      runs
    end
  end

  # A task program written at run time: it ships with its agent as code.
  defp detour_program do
    module = TartarusWarehouse.Program.Detour

    if Code.ensure_loaded?(module) do
      module
    else
      {:ok, [^module]} =
        Tartarus.compile_string("""
        defmodule TartarusWarehouse.Program.Detour do
          @moduledoc "A detour from the usual path, written while the warehouse runs."
          use TartarusWarehouse.Program
          def work(data), do: Enum.reverse(data)
        end
        """)

      module
    end
  end

  @doc """
  `n` jobs of §4.7.5 (Fig. 4.11): the first and the last purely sequential (T1-T4 of
  `thesis_jobs/2`), the others two independent sequences: Fetch -> Carry -> Pack (`:bay`,
  `:line`, `:packing`) and Stamp -> Place (`:stamp`, `:shelf`).

      iex> [a, b] = TartarusWarehouse.Experiment.mixed_jobs(3, 2000) |> Enum.take(2)
      iex> {length(a.tasks), Enum.map(b.tasks, & &1.name)}
      {4, ["Fetch", "Carry", "Pack", "Stamp", "Place"]}
  """
  @spec mixed_jobs(pos_integer(), number()) :: [map()]
  def mixed_jobs(n, ms) do
    [seq | _] = thesis_jobs(1, ms)

    for j <- 1..n do
      if j == 1 or j == n do
        %{seq | id: j}
      else
        %{
          id: j,
          tasks:
            chain([{"Fetch", [:bay]}, {"Carry", [:line]}, {"Pack", [:packing]}], ms) ++
              chain([{"Stamp", [:stamp]}, {"Place", [:shelf]}], ms)
        }
      end
    end
  end

  defp floor!(panel, opts) do
    {:ok, r} = Floor.run(Keyword.put(opts, :status, panel))
    c = Checker.completion(r.history, opts[:jobs])

    Map.merge(r, %{
      violations: length(Checker.violations(r.history)),
      completed_jobs: length(c.completed),
      occupancy: Checker.occupancy(r.history, r.t0_us, 20)
    })
  end

  defp record(:robots, k, state) do
    [v, e] = Enum.filter(state.runs, &(&1.point == k))
    [v1, e1] = Enum.filter(state.runs, &(&1.point == 1))

    state.series
    |> Series.record(:speedup_variable, k, Float.round(v1.makespan_ms / v.makespan_ms, 3))
    |> Series.record(:speedup_equal, k, Float.round(e1.makespan_ms / e.makespan_ms, 3))
    |> Series.record(:makespan_variable_ms, k, round(v.makespan_ms))
    |> Series.record(:makespan_equal_ms, k, round(e.makespan_ms))
    |> Series.record(:mean_busy_robots_equal, k, e.occupancy.mean)
  end

  defp record(:otfp, _, state) do
    stream = Enum.find(state.runs, &(&1.kind == :stream))

    Enum.reduce(per_job(stream), state.series, fn {job, tasks, ms_per_task}, series ->
      series
      |> Series.record(:tasks_in_job, job, tasks)
      |> Series.record(:ms_per_task, job, ms_per_task)
    end)
  end

  defp record(:failover, i, state) do
    r = Enum.find(state.runs, &(&1.point == i and &1.kind == :variable))

    state.series
    |> Series.record(:jobs_lost, i, length(r.jobs) - r.completed_jobs)
    |> Series.record(:makespan_ms, i, round(r.makespan_ms))
  end

  defp record(single, _, state) when single in [:removal, :mixed] do
    [r] = state.runs
    Series.record(state.series, :mean_busy_robots, 1, r.occupancy.mean)
  end

  defp record(:scaling, n, state) do
    [a, c, g] =
      Enum.filter(state.runs, &(&1.point == n and &1.kind in [:agents, :central, :guided]))

    per = fn r -> Float.round(r.makespan_ms / (length(r.jobs) * n), 3) end

    state.series
    |> Series.record(:avg_task_ms_agents, n, per.(a))
    |> Series.record(:avg_task_ms_central, n, per.(c))
    |> Series.record(:avg_task_ms_agents_guided, n, per.(g))
    |> Series.record(:migrations_agents_guided, n, g.migrations)
    |> Series.record(:migrations_agents, n, a.migrations)
  end

  @impl TartarusEmu.Scenario
  def charts(%{p: %{experiment: :robots}}),
    do: [
      %{
        file: "speedup",
        title: "Speed-up over one robot",
        series: [:speedup_variable, :speedup_equal],
        x_label: "robots",
        y_label: "speed-up"
      }
    ]

  def charts(%{p: %{experiment: :otfp}}),
    do: [
      %{
        file: "otfp",
        title: "Tasks per job and ms per task as tasks are added and deleted (Fig. 4.5)",
        series: [:tasks_in_job, :ms_per_task],
        x_label: "job",
        y_label: ""
      }
    ]

  def charts(%{p: %{experiment: single}}) when single in [:removal, :mixed, :failover], do: []

  def charts(_state),
    do: [
      %{
        file: "avg_task_time",
        title: "Average time per task: task agents vs central server (Fig. 4.4)",
        series: [:avg_task_ms_agents, :avg_task_ms_central, :avg_task_ms_agents_guided],
        x_label: "tasks per job",
        y_label: "ms per task"
      }
    ]

  @impl TartarusEmu.Scenario
  def summary(state) do
    p = state.p
    runs = state.runs

    by = fn name ->
      Map.new(Series.points(state.series, name), fn {x, y} -> {to_string(x), y} end)
    end

    base = %{
      experiment: to_string(p.experiment),
      jobs: runs |> Enum.map(&length(&1.jobs)) |> Enum.sum(),
      tasks: runs |> Enum.map(&length(&1.history)) |> Enum.sum(),
      completed_jobs: runs |> Enum.map(& &1.completed_jobs) |> Enum.sum(),
      mutex_violations: runs |> Enum.map(& &1.violations) |> Enum.sum(),
      deadlocks: runs |> Enum.map(&length(&1.timed_out)) |> Enum.sum(),
      scale: p.scale,
      mode: to_string(p.mode),
      wall_ms: runs |> Enum.map(& &1.wall_ms) |> Enum.sum()
    }

    case p.experiment do
      :robots ->
        Map.merge(base, %{
          speedup: by.(:speedup_variable),
          speedup_equal: by.(:speedup_equal),
          makespan_variable_ms: by.(:makespan_variable_ms),
          makespan_equal_ms: by.(:makespan_equal_ms),
          jobs_variable: p.jobs,
          jobs_equal: p.equal_jobs,
          jitter: p.jitter,
          speedup_thesis: Map.new(@thesis_speedup, fn {k, v} -> {to_string(k), v} end)
        })

      :otfp ->
        [gantt] = Enum.filter(runs, &(&1.kind == :variable))
        stream = Enum.find(runs, &(&1.kind == :stream))

        Map.merge(base, %{
          speedup: nil,
          inserted_runs: Enum.count(gantt.history, &(&1.task == "T2A")),
          jobs_with_t2a:
            gantt.history
            |> Enum.filter(&(&1.task == "T2A"))
            |> Enum.map(& &1.job)
            |> Enum.uniq()
            |> Enum.sort(),
          skipped_runs: Enum.count(stream.history ++ gantt.history, & &1.skipped),
          tasks_in_job: by.(:tasks_in_job),
          ms_per_task: by.(:ms_per_task)
        })

      :failover ->
        kept = Enum.filter(runs, &(&1.kind == :variable))
        lost = Enum.find(runs, &(&1.kind == :no_persistence))

        duplicated = fn r ->
          r.history
          |> Enum.frequencies_by(&{&1.job, &1.task})
          |> Enum.count(fn {_, n} -> n > 1 end)
        end

        Map.merge(base, %{
          speedup: nil,
          seeds: Enum.map(kept, & &1.run_seed),
          kills: kept |> Enum.map(&length(&1.killed_at_us)) |> Enum.sum(),
          jobs_lost: kept |> Enum.map(&(length(&1.jobs) - &1.completed_jobs)) |> Enum.sum(),
          jobs_duplicated: kept |> Enum.map(duplicated) |> Enum.sum(),
          jobs_lost_by_seed:
            Map.new(kept, &{to_string(&1.run_seed), length(&1.jobs) - &1.completed_jobs}),
          makespan_ms_by_seed: Map.new(kept, &{to_string(&1.run_seed), round(&1.makespan_ms)}),
          jobs_lost_without_persistence: length(lost.timed_out),
          # The runs without persistence are not counted in jobs/completed_jobs/deadlocks.
          jobs: kept |> Enum.map(&length(&1.jobs)) |> Enum.sum(),
          completed_jobs: kept |> Enum.map(& &1.completed_jobs) |> Enum.sum(),
          deadlocks: kept |> Enum.map(&length(&1.timed_out)) |> Enum.sum(),
          tasks: kept |> Enum.map(&length(&1.history)) |> Enum.sum()
        })

      :removal ->
        [r] = runs

        jobs_of = fn robot ->
          r.history
          |> Enum.filter(&(&1.robot == robot))
          |> Enum.map(& &1.job)
          |> Enum.uniq()
          |> Enum.sort()
        end

        Map.merge(base, %{
          speedup: nil,
          removed_robot: "r2",
          joined_robot: "r4",
          jobs_per_robot: Map.new(r.robots, &{&1, jobs_of.(&1)}),
          mean_busy_robots: r.occupancy.mean
        })

      :mixed ->
        [r] = runs

        overlapping =
          for j <- r.jobs,
              [a, b] <- [
                r.history
                |> Enum.filter(&(&1.job == j))
                |> Enum.group_by(& &1.seq)
                |> Map.values()
              ],
              span(a) |> overlaps?(span(b)),
              do: j

        Map.merge(base, %{
          speedup: nil,
          jobs_with_concurrent_sequences: overlapping,
          mean_busy_robots: r.occupancy.mean
        })

      :scaling ->
        agents = by.(:avg_task_ms_agents)
        central = by.(:avg_task_ms_central)

        big =
          case Enum.find(runs, &(&1.kind == :big)) do
            nil ->
              nil

            r ->
              %{
                robots: length(r.robots),
                jobs: length(r.jobs),
                completed_jobs: r.completed_jobs,
                mutex_violations: r.violations,
                wall_ms: r.wall_ms,
                makespan_ms: round(r.makespan_ms),
                migrations: r.migrations
              }
          end

        Map.merge(base, %{
          big_run: big,
          speedup: nil,
          avg_task_ms_agents: agents,
          avg_task_ms_central: central,
          avg_task_ms_agents_guided: by.(:avg_task_ms_agents_guided),
          agents_faster_at:
            for({n, a} <- agents, a < central[n], do: String.to_integer(n)) |> Enum.sort(),
          slope_ms_per_task: %{
            agents: slope(agents),
            central: slope(central),
            agents_guided: slope(by.(:avg_task_ms_agents_guided))
          },
          latency_ms: p.latency_ms,
          server_ms: p.server_ms,
          nodes: p.nodes,
          robots: p.scaling_robots,
          jobs_per_run: p.scaling_jobs
        })
    end
  end

  # Least-squares slope of ms per task against tasks per job (keys are strings).
  defp slope(points) when map_size(points) < 2, do: nil

  defp slope(points) do
    xy = for {n, y} <- points, do: {String.to_integer(n) * 1.0, y * 1.0}
    k = length(xy)
    mx = Enum.sum(Enum.map(xy, &elem(&1, 0))) / k
    my = Enum.sum(Enum.map(xy, &elem(&1, 1))) / k
    sxy = Enum.sum(for {x, y} <- xy, do: (x - mx) * (y - my))
    sxx = Enum.sum(for {x, _} <- xy, do: (x - mx) * (x - mx))
    Float.round(sxy / sxx, 4)
  end

  defp span(entries),
    do:
      {entries |> Enum.map(& &1.start_us) |> Enum.min(),
       entries |> Enum.map(& &1.stop_us) |> Enum.max()}

  defp overlaps?({a0, a1}, {b0, b1}), do: a0 < b1 and b0 < a1

  # Per job of a run: tasks run (not skipped) and the job's time per task.
  defp per_job(r) do
    r.history
    |> Enum.reject(& &1.skipped)
    |> Enum.group_by(& &1.job)
    |> Enum.sort()
    |> Enum.map(fn {job, es} ->
      {t0, t1} = span(es)
      {job, length(es), Float.round((t1 - t0) / 1000 / length(es), 3)}
    end)
  end

  @impl TartarusEmu.Scenario
  def comparisons(%{p: %{experiment: :robots}} = state) do
    ours = Map.new(Series.points(state.series, :speedup_variable))

    for {k, thesis} <- Enum.sort(@thesis_speedup), Map.has_key?(ours, k) do
      %{metric: "speed-up on #{k} robots (variable durations)", ours: ours[k], thesis: thesis}
    end
  end

  def comparisons(_state), do: []

  @impl TartarusEmu.Scenario
  def write(state, dir) do
    rows =
      for r <- state.runs, e <- r.history do
        [
          r.point,
          r.kind,
          e.robot,
          e.job,
          e.task,
          Enum.join(Enum.map(e.resources, &inspect/1), " "),
          Float.round((e.start_us - r.t0_us) / 1000, 3),
          Float.round((e.stop_us - r.t0_us) / 1000, 3),
          Float.round(e.ms, 3)
        ]
      end

    csv =
      Report.write_csv!(
        dir,
        "executions",
        ["point", "run", "robot", "job", "task", "resources", "start_ms", "stop_ms", "ms"],
        rows
      )

    gantts =
      for r <- state.runs,
          r.kind in [:variable, :agents] and (r.kind == :variable or r.point == hd(state.points)) do
        rows =
          Enum.map(r.robots, fn robot ->
            spans =
              for e <- r.history, e.robot == robot do
                %{
                  start: (e.start_us - r.t0_us) / 1000,
                  stop: (e.stop_us - r.t0_us) / 1000,
                  label: "J#{e.job}",
                  group: e.task
                }
              end

            %{label: robot, spans: spans}
          end)

        {what, file} =
          case state.p.experiment do
            :robots ->
              {"#{r.point} robot(s), variable durations", "gantt_#{r.point}_robots.svg"}

            :scaling ->
              {"#{r.point} tasks per job, agents", "gantt_#{r.point}_tasks.svg"}

            :otfp ->
              {"T2A added, deleted and added again on the fly (Fig. 4.12)", "gantt_otfp.svg"}

            :removal ->
              {"r2 leaves after 2 jobs, r4 joins after 4 (Fig. 4.13)", "gantt_removal.svg"}

            :mixed ->
              {"sequential and independent sequences (Fig. 4.11)", "gantt_mixed.svg"}

            :failover ->
              {"the distributor's host killed twice, seed #{r.run_seed}",
               "gantt_failover_seed_#{r.run_seed}.svg"}
          end

        by_robot =
          SVG.write!(
            Path.join(dir, file),
            SVG.gantt(rows, title: "Warehouse: #{what}", x_label: "ms")
          )

        # As the thesis draws them: a row per job, bars coloured by robot, labelled with
        # the task and the ms it took.
        job_rows =
          Enum.map(r.jobs, fn job ->
            spans =
              for e <- r.history, e.job == job, not e.skipped do
                %{
                  start: (e.start_us - r.t0_us) / 1000,
                  stop: (e.stop_us - r.t0_us) / 1000,
                  label: "#{e.task} #{round(e.ms)}",
                  group: e.robot
                }
              end

            %{label: "J#{job}", spans: spans}
          end)

        by_job =
          SVG.write!(
            Path.join(dir, String.replace_suffix(file, ".svg", "_by_job.svg")),
            SVG.gantt(job_rows, title: "Warehouse: #{what}, by job", x_label: "ms")
          )

        [by_robot, by_job]
      end

    [csv | List.flatten(gantts)]
  end

  @doc """
  `n` jobs of the warehouse's four sequential tasks (§4.7.4): T1 leave the bay (`:bay`),
  T2 follow the line to the rack (`:line`, `:rack`), T3 follow the wall to the packing
  zone (`:wall`, `:packing`), T4 back to the bay's line (`:return`), each of ideal
  duration `ms`.

      iex> [j | _] = TartarusWarehouse.Experiment.thesis_jobs(2, 2000)
      iex> Enum.map(j.tasks, & &1.name)
      ["T1", "T2", "T3", "T4"]
  """
  @spec thesis_jobs(pos_integer(), number()) :: [map()]
  def thesis_jobs(n, ms) do
    resources = [[:bay], [:line, :rack], [:wall, :packing], [:return]]

    for j <- 1..n do
      %{id: j, tasks: chain(Enum.zip(["T1", "T2", "T3", "T4"], resources), ms)}
    end
  end

  @doc """
  `n` jobs of `tasks` soft tasks each (§4.7.2: Sort, Merge, Add, Sub, Div repeating), task
  `i` needing resource `{:psi, i}`, each of ideal duration `ms`.

      iex> [j] = TartarusWarehouse.Experiment.soft_jobs(1, 7, 2000)
      iex> {length(j.tasks), List.last(j.tasks).program}
      {7, TartarusWarehouse.Program.Merge}
  """
  @spec soft_jobs(pos_integer(), pos_integer(), number()) :: [map()]
  def soft_jobs(n, tasks, ms) do
    programs = TartarusWarehouse.Program.soft(tasks)

    for j <- 1..n do
      specs = for {p, i} <- Enum.with_index(programs, 1), do: {"T#{i}", [{:psi, i}], p}
      %{id: j, tasks: chain(specs, ms)}
    end
  end

  defp chain(specs, ms) do
    specs
    |> Enum.with_index()
    |> Enum.map(fn {spec, i} ->
      {name, rs, program} =
        case spec do
          {name, rs} -> {name, rs, TartarusWarehouse.Program.Work}
          {name, rs, p} -> {name, rs, p}
        end

      prev = if i > 0, do: [elem(Enum.at(specs, i - 1), 0)], else: []
      %{name: name, resources: rs, after: prev, program: program, duration_ms: ms}
    end)
  end
end
