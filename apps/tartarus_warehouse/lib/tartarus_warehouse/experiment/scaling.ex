defmodule TartarusWarehouse.Experiment.Scaling do
  @moduledoc """
  `mix tartarus.warehouse --experiment scaling` (thesis §4.7.2, Fig. 4.4) under the
  thesis's load: for each job size n of `sizes` and each of `seeds` seeds, `scaling_jobs`
  jobs of n soft tasks (Sort, Merge, Add, Sub, Div repeating; task i needing its own
  resource, equal durations), all submitted at the start so the pipeline stays full, on a
  network of `nodes` nodes: `scaling_robots` robots (R), `phi_nodes` shared-resource nodes
  (Φ), the rest secondary (Σ), and the distributor's node. Each point runs the floors of
  `designs`: the central server (3 messages a task), the thesis's blind task agents
  returning to the distributor after each block (`agents`) or continuing to the next
  job's robot (`agents_continue`), and the guided agents likewise (`guided`,
  `guided_continue`); the central server and the Job Distributor are each charged
  `service_ms` per message (`TartarusWarehouse.Service`).

  The metric (`steady/2`): the mean over the jobs but the first and last `drop` of each
  job's span (first start to last stop) over its tasks; the medians over the seeds per
  size. Beside it: each central process's utilisation and queue over the steady-state
  window, the prediction of the utilisation formula (`predict/2`, `predicted_knee/1`), the
  knee of the central curve (`TartarusTools.Stats.hinge_fit/2`), and where each agents'
  curve crosses the central one. With `big_robots` > 0 the last point of the first seed
  also runs 20 jobs of 5 soft tasks in 20 independent pipelines on that many robots,
  agents guided (`big_run` in the summary).
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusTools.Stats
  alias TartarusWarehouse.Experiment.Jobs
  alias TartarusWarehouse.Service

  @designs [:central, :agents, :agents_continue, :guided, :guided_continue]
  # The messages a task costs the central server (started, finished, the command).
  @central_messages 3
  # The bins (ms) of the service timelines.
  @bin_ms 50

  @labels %{
    central: "central server",
    agents: "task agents, blind, returning (the thesis's)",
    agents_continue: "task agents, blind, continuing",
    guided: "task agents, guided, returning",
    guided_continue: "task agents, guided, continuing"
  }

  @impl Experiment
  def kinds, do: @designs ++ [:big]

  @impl Experiment
  def points(p), do: p.sizes

  # Arms are the job sizes, each on seeds seed..seed + seeds - 1 (a point is {n, seed}).
  @impl Experiment
  def sweep(state) do
    %{
      arms: Enum.map(state.p.sizes, &{to_string(&1), &1}),
      seeds: Enum.map(0..(state.p.seeds - 1), &(state.seed + &1)),
      point: fn n, seed -> {n, seed} end
    }
  end

  @impl Experiment
  def runs({n, seed}, state) do
    p = state.p
    jobs = Jobs.soft_jobs(jobs_for(n, p), n, 2000)

    big =
      if p.big_robots > 0 and n == List.last(p.sizes) and seed == state.seed do
        [
          {:big,
           [
             robots: p.big_robots,
             jobs: big_jobs(),
             scale: p.scale,
             guide: true,
             seed: seed,
             mode: p.mode,
             timeout_ms: p.timeout_ms
           ], %{run_seed: seed}}
        ]
      else
        []
      end

    big ++
      for kind <- Enum.filter(@designs, &(&1 in p.designs)) do
        {kind,
         [
           robots: p.scaling_robots,
           phi: p.phi_nodes,
           phi_agents: p.phi_agents,
           secondary: p.nodes - p.scaling_robots - p.phi_nodes - 1,
           jobs: jobs,
           scale: p.scale,
           design: if(kind == :central, do: :central, else: :agents),
           guide: kind in [:guided, :guided_continue],
           continue: kind in [:agents_continue, :guided_continue],
           seed: seed,
           mode: p.mode,
           latency_ms: p.latency_ms,
           service_ms: p.service_ms,
           timeout_ms: p.timeout_ms
         ], %{run_seed: seed}}
      end
  end

  # 20 jobs of 5 soft tasks, job j's task i needing {:psi, i, j}: 20 independent pipelines.
  defp big_jobs do
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
  end

  @doc """
  The jobs a point of `n` tasks per job runs: `scaling_jobs` when it is a count, a·n + b
  when it is `{:per_size, a, b}`.

      iex> TartarusWarehouse.Experiment.Scaling.jobs_for(30, %{scaling_jobs: {:per_size, 1, 20}})
      50
      iex> TartarusWarehouse.Experiment.Scaling.jobs_for(30, %{scaling_jobs: 120})
      120
  """
  @spec jobs_for(pos_integer(), map()) :: pos_integer()
  def jobs_for(n, %{scaling_jobs: {:per_size, a, b}}), do: a * n + b
  def jobs_for(_n, %{scaling_jobs: jobs}), do: jobs

  @doc """
  The steady-state reading of one floor's run (`TartarusWarehouse.Floor.run/1`'s result,
  jobs in submission order): `avg_task_ms`, the mean over the jobs but the first and last
  `drop` (all of them when fewer would be left) of each job's span (its first task's start
  to its last task's stop) over its tasks; `jobs`, how many were counted; and `window`,
  `{from_us, to_us}` (system µs) from the first start to the last stop of those jobs.

      iex> h = [%{job: 1, start_us: 0, stop_us: 10_000, skipped: false},
      ...>      %{job: 1, start_us: 10_000, stop_us: 22_000, skipped: false},
      ...>      %{job: 2, start_us: 10_000, stop_us: 20_000, skipped: false}]
      iex> TartarusWarehouse.Experiment.Scaling.steady(%{jobs: [1, 2], history: h}, 0)
      %{avg_task_ms: 10.5, jobs: 2, window: {0, 22000}}
  """
  @spec steady(map(), non_neg_integer()) :: map()
  def steady(run, drop) do
    ids = run.jobs
    kept = if length(ids) > 2 * drop, do: Enum.slice(ids, drop, length(ids) - 2 * drop), else: ids
    kept_set = MapSet.new(kept)

    by_job =
      run.history
      |> Enum.filter(&(MapSet.member?(kept_set, &1.job) and not &1.skipped))
      |> Enum.group_by(& &1.job)

    per_task =
      for {_job, es} <- by_job do
        {t0, t1} = Experiment.span(es)
        (t1 - t0) / 1000 / length(es)
      end

    all = Enum.flat_map(by_job, &elem(&1, 1))

    %{
      avg_task_ms: if(per_task == [], do: nil, else: Float.round(Stats.mean(per_task), 3)),
      jobs: length(per_task),
      window: if(all == [], do: nil, else: Experiment.span(all))
    }
  end

  @doc """
  The knee the utilisation formula predicts (tasks per job): with c tasks at once, m = 3
  messages a task of T = 2000 × scale ms and S = `service_ms` a message, the central
  server saturates at c* = T / (m·S); with a robot a job, c is the jobs in flight, n in
  steady state.

      iex> TartarusWarehouse.Experiment.Scaling.predicted_knee(%{scale: 0.1, service_ms: 2.2})
      30.303
  """
  @spec predicted_knee(map()) :: float() | nil
  def predicted_knee(%{service_ms: s}) when s <= 0, do: nil

  def predicted_knee(p),
    do: Float.round(2000 * p.scale / (@central_messages * p.service_ms), 3)

  @doc """
  The central server's time per task the utilisation formula predicts for jobs of `n`
  tasks (`p`: `scale`, `service_ms`, `scaling_jobs`, `drop`): each pipeline slot lasts
  max(T, 3·c·S) with c the jobs in flight at that slot (fewer than n in the fill and the
  drain), a job's span is the sum over its n slots, and the metric the mean over the jobs
  counted (`steady/2`) of span / n. Hand-over times are left out (0 at no load).

      iex> p = %{scale: 0.1, service_ms: 2.2, scaling_jobs: 120, drop: 10}
      iex> for n <- [30, 60], do: TartarusWarehouse.Experiment.Scaling.predict(n, p)
      [200.0, 353.251]
  """
  @spec predict(pos_integer(), map()) :: float()
  def predict(n, p) do
    t = 2000 * p.scale
    jobs = jobs_for(n, p)
    drop = if jobs > 2 * p.drop, do: p.drop, else: 0
    in_flight = fn slot -> min(slot, jobs) - max(1, slot - n + 1) + 1 end
    slot_ms = fn slot -> max(t, @central_messages * in_flight.(slot) * p.service_ms) end

    per_job =
      for j <- (drop + 1)..(jobs - drop) do
        Enum.sum(Enum.map(j..(j + n - 1), slot_ms)) / n
      end

    Float.round(Stats.mean(per_job), 3)
  end

  @impl Experiment
  def record({n, _seed} = point, state) do
    # The medians over the seeds run so far for this size (the last seed's call leaves the
    # medians of all of them).
    runs = Enum.filter(state.runs, &(match?({^n, _}, &1.point) and &1.kind in @designs))

    series =
      Enum.reduce(@designs, state.series, fn kind, series ->
        case for(r <- runs, r.kind == kind, v = steady(r, state.p.drop).avg_task_ms, do: v) do
          [] -> series
          vs -> Series.record(series, :"avg_task_ms_#{name(kind)}", n, Stats.median(vs))
        end
      end)

    timelines(point, runs, series, state)
  end

  # The service timelines (utilisation and queue over time) of the largest size on the
  # first seed: the central server and the distributors of the returning agents.
  defp timelines({n, seed}, runs, series, state) do
    if n == List.last(state.p.sizes) and seed == state.seed do
      Enum.reduce(runs, series, fn r, series ->
        if r.run_seed == seed and r.kind in [:central, :agents, :guided] do
          t0 = r.t0_us + r.mono_offset_us
          t1 = t0 + round(r.makespan_ms * 1000)

          r.service_log
          |> Service.timeline(t0, t1, @bin_ms)
          |> Enum.reduce(series, fn {t, busy, queue}, series ->
            series
            |> Series.record(:"queue_#{r.kind}", t, queue)
            |> Series.record(:"busy_#{r.kind}", t, busy)
          end)
        else
          series
        end
      end)
    else
      series
    end
  end

  # The summary's name of a design: avg_task_ms_<name>.
  defp name(:central), do: "central"
  defp name(:agents), do: "agents"
  defp name(:agents_continue), do: "agents_continue"
  defp name(:guided), do: "agents_guided"
  defp name(:guided_continue), do: "agents_guided_continue"

  @impl Experiment
  def charts(state) do
    p = state.p
    kinds = Enum.filter(@designs, &(&1 in p.designs))
    keys = Enum.map(kinds, &:"avg_task_ms_#{name(&1)}")

    predicted =
      if :central in kinds and p.service_ms > 0,
        do: [
          %{
            name: "central, predicted (utilisation formula)",
            points: Enum.map(p.sizes, &{&1, predict(&1, p)})
          }
        ],
        else: []

    fig = %{
      file: "avg_task_time",
      title: "Average time per task against tasks per job (Fig. 4.4)",
      subtitle:
        "#{p.scaling_robots} robots, #{jobs_text(p.scaling_jobs)} jobs a point (the first and last #{p.drop} not counted), L = #{p.latency_ms} ms a link, tasks of #{fmt(2000 * p.scale)} ms, S = #{fmt(p.service_ms)} ms a message; medians of seeds #{seeds_text(state)}",
      series: keys,
      labels: Map.new(kinds, &{:"avg_task_ms_#{name(&1)}", @labels[&1]}),
      references: predicted,
      x_label: "tasks per job",
      y_label: "time per task",
      y_unit: "ms",
      y_min: 0
    }

    service =
      for {what, unit, key} <- [{"queue", "messages", :queue}, {"busy", nil, :busy}],
          series = for(k <- [:central, :agents, :guided], k in kinds, do: :"#{key}_#{k}"),
          series != [] do
        %{
          file: "service_#{what}",
          title:
            if(key == :queue,
              do: "Messages waiting or in service at the central process",
              else: "Utilisation of the central process (busy fraction per #{@bin_ms} ms)"
            ),
          subtitle:
            "#{List.last(p.sizes)} tasks per job, seed #{state.seed}, S = #{fmt(p.service_ms)} ms a message",
          series: series,
          labels:
            Map.new(series, fn s ->
              kind = s |> to_string() |> String.split("_", parts: 2) |> List.last()

              {s,
               case kind do
                 "central" -> "central server"
                 "agents" -> "distributor, blind agents returning"
                 "guided" -> "distributor, guided agents returning"
               end}
            end),
          x_label: "time",
          x_unit: "ms",
          y_label: if(key == :queue, do: "queue", else: "busy"),
          y_unit: unit,
          y_min: 0
        }
      end

    [fig | service]
  end

  defp jobs_text({:per_size, a, b}), do: "#{if a == 1, do: "", else: a}n + #{b}"
  defp jobs_text(jobs), do: to_string(jobs)

  defp seeds_text(state), do: Enum.map_join(0..(state.p.seeds - 1), ", ", &(state.seed + &1))

  defp fmt(x) when is_float(x), do: TartarusTools.CLI.show(x)
  defp fmt(x), do: to_string(x)

  @impl Experiment
  def summary(base, state) do
    p = state.p
    kinds = Enum.filter(@designs, &(&1 in p.designs))
    runs = Enum.filter(state.runs, &(&1.kind in kinds))

    readings =
      Map.new(runs, fn r ->
        st = steady(r, p.drop)

        service =
          case st.window do
            {from, to} when to > from ->
              off = r.mono_offset_us
              Service.stats(r.service_log, from + off, to + off)

            _ ->
              nil
          end

        {{r.kind, elem(r.point, 0), r.run_seed}, %{steady: st, service: service}}
      end)

    curves =
      Map.new(kinds, fn kind ->
        {kind, Experiment.by(state, :"avg_task_ms_#{name(kind)}")}
      end)

    by_seed =
      Map.new(kinds, fn kind ->
        {"#{name(kind)}",
         Map.new(p.sizes, fn n ->
           {to_string(n),
            for({{^kind, ^n, _}, v} <- Enum.sort(readings), do: v.steady.avg_task_ms)}
         end)}
      end)

    med = fn kind, key ->
      Map.new(p.sizes, fn n ->
        vs = for {{^kind, ^n, _}, %{service: %{} = sv}} <- readings, do: sv[key]
        {to_string(n), Stats.median(vs)}
      end)
    end

    utilisation =
      Map.new(kinds, fn kind ->
        who = if kind == :central, do: "central", else: "distributor_#{name(kind)}"
        {who, med.(kind, :busy)}
      end)

    max_queue =
      Map.new(kinds, fn kind ->
        who = if kind == :central, do: "central", else: "distributor_#{name(kind)}"
        {who, med.(kind, :max_queue)}
      end)

    central = Map.get(curves, :central, %{})
    central_pts = for {n, y} <- central, y != nil, do: {String.to_integer(n), y}
    fit = if length(central_pts) >= 3, do: Stats.hinge_fit(central_pts)
    knee = predicted_knee(p)
    min_c = central_pts |> Enum.map(&elem(&1, 1)) |> Enum.min(fn -> nil end)
    last = to_string(List.last(p.sizes))

    rise = if min_c && central[last], do: Float.round(central[last] / min_c, 3)

    crossings =
      for kind <- kinds, kind != :central, into: %{} do
        {"#{name(kind)}", crossing(curves[kind], central)}
      end

    knee_ok = fit != nil and knee != nil and fit.b > 0 and abs(fit.knee - knee) <= 0.25 * knee

    Map.merge(curves |> Map.new(fn {k, v} -> {:"avg_task_ms_#{name(k)}", v} end), %{
      big_run: big_run(Enum.find(state.runs, &(&1.kind == :big))),
      speedup: nil,
      avg_task_ms_by_seed: by_seed,
      utilisation: utilisation,
      max_queue: max_queue,
      predicted_knee: knee,
      predicted_central_ms: Map.new(p.sizes, &{to_string(&1), predict(&1, p)}),
      central_fit: fit,
      central_rise: rise,
      crossings: crossings,
      pass: %{
        rise: rise != nil and rise >= 1.2,
        knee: knee_ok,
        exclusion: base.mutex_violations == 0 and base.deadlocks == 0
      },
      latency_ms: p.latency_ms,
      service_ms: p.service_ms,
      nodes: p.nodes,
      robots: p.scaling_robots,
      phi_nodes: p.phi_nodes,
      phi_agents: p.phi_agents,
      jobs_per_run: jobs_text(p.scaling_jobs),
      hops_per_task: hops_per_task(runs, p),
      thesis: Map.new(kinds -- [:central], &{"#{name(&1)}", criteria(central, curves[&1])}),
      drop: p.drop,
      seeds: Enum.map(0..(p.seeds - 1), &(state.seed + &1))
    })
    |> Map.merge(base, fn _k, mine, _base -> mine end)
  end

  # Per agents' design and size: the median over the seeds of the migrations a task executed
  # cost (the search for the robot and the way back to it after a return).
  defp hops_per_task(runs, p) do
    for kind <- [:agents, :agents_continue, :guided, :guided_continue],
        kind in p.designs,
        into: %{} do
      {"#{name(kind)}",
       Map.new(p.sizes, fn n ->
         vs =
           for r <- runs,
               r.kind == kind,
               elem(r.point, 0) == n,
               done = Enum.count(r.history, &(not &1.skipped)),
               done > 0,
               do: r.migrations / done

         {to_string(n), if(vs == [], do: nil, else: Float.round(Stats.median(vs), 2))}
       end)}
    end
  end

  @doc """
  The thesis's four statements on Fig. 4.4 (§4.7.2), judged on the medians of the central
  curve and one agents' curve (each keyed by tasks per job as strings), as registered in
  docs/warehouse.md ("Fig. 4.4 in virtual time"): the sizes below 30 are `small`, 30 the
  knee, the largest size `last`.

    * `a` - below about 30 the central server is at most a little better: at every small
      size the agents take at most 1.10 × the central time per task;
    * `b` - beyond, the central server degrades rapidly: its time per task at the largest
      size is at least 1.25 × its time at 30;
    * `c` - the agents' time per task grows gradually: at the largest size at most 1.25 ×
      its time at 30;
    * `d` - the curves cross: the agents are slower than (or level with) the central
      server at the smallest size and faster at the largest.

  Each is `%{pass: boolean, ...}` with the figures it was judged on; nil when a size it
  needs is missing.

      iex> c = %{"5" => 2000.0, "30" => 2000.0, "60" => 2600.0}
      iex> a = %{"5" => 2100.0, "30" => 2150.0, "60" => 2300.0}
      iex> r = TartarusWarehouse.Experiment.Scaling.criteria(c, a)
      iex> {r.a.pass, r.b.pass, r.c.pass, r.d.pass}
      {true, true, true, true}
  """
  @spec criteria(map(), map() | nil) :: map() | nil
  def criteria(_central, nil), do: nil

  def criteria(central, agents) do
    sizes = central |> Map.keys() |> Enum.map(&String.to_integer/1) |> Enum.sort()
    at = fn curve, n -> curve[to_string(n)] end

    if sizes == [] or 30 not in sizes or Enum.any?(sizes, &(at.(agents, &1) == nil)) do
      nil
    else
      {first, last} = {List.first(sizes), List.last(sizes)}
      small = Enum.filter(sizes, &(&1 < 30))
      ratio = fn x, y -> if y && y > 0, do: Float.round(x / y, 3) end
      small_ratios = Map.new(small, &{to_string(&1), ratio.(at.(agents, &1), at.(central, &1))})
      b = ratio.(at.(central, last), at.(central, 30))
      c = ratio.(at.(agents, last), at.(agents, 30))

      %{
        a: %{
          pass: Enum.all?(small_ratios, fn {_, r} -> r <= 1.10 end),
          agents_over_central: small_ratios
        },
        b: %{pass: b >= 1.25, central_last_over_30: b},
        c: %{pass: c <= 1.25, agents_last_over_30: c},
        d: %{
          pass:
            at.(agents, first) >= at.(central, first) and at.(agents, last) < at.(central, last),
          first: %{central: at.(central, first), agents: at.(agents, first)},
          last: %{central: at.(central, last), agents: at.(agents, last)}
        }
      }
    end
  end

  @doc """
  Where an agents' curve crosses the central one (both keyed by tasks per job as
  strings): `below_at`, the sizes at which the agents take less time per task;
  `below_from`, the smallest size from which they stay below at every larger size (nil
  if they are not below at the largest).

      iex> a = %{"5" => 3.0, "10" => 2.0, "20" => 2.0}
      iex> c = %{"5" => 2.0, "10" => 2.5, "20" => 3.0}
      iex> TartarusWarehouse.Experiment.Scaling.crossing(a, c)
      %{below_at: [10, 20], below_from: 10}
  """
  @spec crossing(map() | nil, map()) :: map()
  def crossing(nil, _central), do: %{below_at: [], below_from: nil}

  def crossing(agents, central) do
    sizes =
      agents
      |> Map.keys()
      |> Enum.filter(&(central[&1] != nil and agents[&1] != nil))
      |> Enum.map(&String.to_integer/1)
      |> Enum.sort()

    below = for n <- sizes, agents[to_string(n)] < central[to_string(n)], do: n

    from =
      sizes
      |> Enum.reverse()
      |> Enum.take_while(&(&1 in below))
      |> List.last()

    %{below_at: below, below_from: from}
  end

  defp big_run(nil), do: nil

  defp big_run(r) do
    %{
      robots: length(r.robots),
      jobs: length(r.jobs),
      completed_jobs: r.completed_jobs,
      mutex_violations: r.violations,
      wall_ms: r.wall_ms,
      duration_ms: r.duration_ms,
      makespan_ms: round(r.makespan_ms),
      migrations: r.migrations
    }
  end

  @impl Experiment
  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s) do
    curves =
      for k <- @designs,
          key = :"avg_task_ms_#{name(k)}",
          Map.has_key?(s, key),
          do: "ms per task (steady state), #{@labels[k]}: #{TartarusTools.CLI.show(s[key])}"

    Enum.join(
      curves ++
        [
          "central knee (hinge fit): #{TartarusTools.CLI.show(s.central_fit && s.central_fit.knee)}, predicted #{TartarusTools.CLI.show(s.predicted_knee)}; rise at the largest size #{TartarusTools.CLI.show(s.central_rise)}",
          "utilisation: #{TartarusTools.CLI.show(s.utilisation)}",
          "hops per task: #{TartarusTools.CLI.show(s.hops_per_task)}"
        ] ++
        for {design, %{} = c} <- s.thesis do
          "thesis's statements (#{design}): " <>
            Enum.map_join(
              [:a, :b, :c, :d],
              ", ",
              &"(#{&1}) #{if c[&1].pass, do: "pass", else: "fail"}"
            )
        end,
      "\n"
    )
  end
end
