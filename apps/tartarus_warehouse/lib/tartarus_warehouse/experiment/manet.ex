defmodule TartarusWarehouse.Experiment.Manet do
  @moduledoc """
  `mix tartarus.warehouse --experiment manet` (thesis §4.3: the network is a MANET, "a
  node can connect or disconnect to another node at any point of time"): `--manet-jobs`
  warehouse jobs (T1-T4, variable durations) on `--manet-robots` k robots that are not
  linked to each other: they meet through k secondary nodes (Σ, a ring: Σ node i on
  robots i and i + 1) and the distributor's node, so the agents cross Σ nodes. While the
  jobs run, robots and Σ nodes leave the network (every link of theirs down:
  `TartarusEmu.Network.isolate/2`; what runs on a robot goes on) and rejoin it: a
  `TartarusEmu.Dynamics` process over the 2k nodes, one tick a quarter of a task's time,
  each node up breaking off with probability p a tick and each node down rejoining with
  probability 1/2 (a down spell lasts two ticks on average), every node back once the
  schedule's horizon ((m + 4) · 4 · t) passed. Arms: each p of `--churn` (0: the static
  network); seeds: `--seeds` from `--seed`. Per floor: violations (Eq. 4.1), jobs done,
  jobs not done (the floor reports them: `timed_out`), the makespan, the disconnections
  applied, the nodes' down fraction, the agents' migrations and their arrivals at Σ nodes,
  robots and `jd`.
  """
  use TartarusWarehouse.Experiment.Kind

  alias TartarusEmu.Dynamics
  alias TartarusWarehouse.Experiment.Jobs
  alias TartarusWarehouse.Floor.Options

  # a node down rejoins with this probability a tick
  @heal 0.5

  @impl Experiment
  def kinds, do: [:manet]

  @impl Experiment
  def points(p), do: for(c <- p.churn, s <- Experiment.seeds(p), do: {c, s})

  @impl Experiment
  def sweep(state) do
    %{
      arms: Enum.map(state.p.churn, &{arm(&1), &1}),
      seeds: Experiment.seeds(%{seed: state.seed, seeds: state.p.seeds}),
      point: fn c, seed -> {c, seed} end
    }
  end

  defp arm(c), do: "p=#{c}"

  @doc """
  The schedule of nodes leaving and rejoining: `{{:ms, t}, {:disconnect | :reconnect,
  node}}` events of a `TartarusEmu.Dynamics` process over `nodes` (seeded by `seed`),
  a tick every `tick_ms`, each node up breaking off with probability `p` a tick, each
  node down rejoining with probability 1/2, for `ticks` ticks; then every node still down
  rejoins.

      iex> TartarusWarehouse.Experiment.Manet.schedule(["r1", "s1"], 0.0, 10, 5, 1)
      []
      iex> ev = TartarusWarehouse.Experiment.Manet.schedule(["r1", "s1"], 1.0, 10, 1, 1)
      iex> ev
      [{{:ms, 10}, {:disconnect, "r1"}}, {{:ms, 10}, {:disconnect, "s1"}}, {{:ms, 20}, {:reconnect, "r1"}}, {{:ms, 20}, {:reconnect, "s1"}}]
  """
  @spec schedule([String.t()], float(), pos_integer(), non_neg_integer(), integer()) :: [tuple()]
  def schedule(nodes, p, tick_ms, ticks, seed) do
    {events, state, _rng} =
      Dynamics.run(Dynamics.new(nodes), {p, @heal}, ticks, Dynamics.rng(seed))

    tagged =
      for {tick, {what, node}} <- events,
          do:
            {{:ms, tick * tick_ms}, {if(what == :down, do: :disconnect, else: :reconnect), node}}

    tagged ++
      for node <- Dynamics.down(state), do: {{:ms, (ticks + 1) * tick_ms}, {:reconnect, node}}
  end

  @impl Experiment
  def runs({c, seed}, state) do
    p = state.p
    k = p.manet_robots
    t = 2000 * p.scale
    tick = max(round(t / 4), 1)
    ticks = div((p.manet_jobs + 4) * 4 * round(t), tick)
    events = schedule(Options.leaving_nodes(k, k), c, tick, ticks, seed)

    opts = [
      robots: k,
      secondary: k,
      robot_mesh: false,
      jobs: Jobs.thesis_jobs(p.manet_jobs, 2000),
      jitter: p.jitter,
      latency_ms: p.latency_ms,
      events: events
    ]

    [
      {:manet, Experiment.floor(state, seed) ++ opts,
       %{run_seed: seed, churn: c, schedule: events, tick_ms: tick, ticks: ticks}}
    ]
  end

  @doc "What one floor measured (see the module's doc)."
  @spec measure(map()) :: map()
  def measure(r) do
    disconnections = Enum.count(r.schedule, &match?({_, {:disconnect, _}}, &1))
    applied = Enum.count(r.applied_events, &match?(%{event: {:disconnect, _}}, &1))
    {a, b} = if r.history == [], do: {0, 0}, else: Experiment.span(r.history)

    %{
      violations: r.violations,
      jobs: length(r.jobs),
      done: r.completed_jobs,
      not_done_reported: length(r.timed_out),
      makespan_ms: Float.round((b - a) / 1000, 3),
      disconnections_scheduled: disconnections,
      disconnections_applied: applied,
      down_fraction: down_fraction(r),
      migrations: r.migrations,
      arrivals_at_sigma: sum_arrivals(r, "s"),
      arrivals_at_robots: sum_arrivals(r, "r"),
      arrivals_at_jd: Map.get(r.arrivals_by_node, "jd", 0)
    }
  end

  defp sum_arrivals(r, prefix),
    do:
      r.arrivals_by_node
      |> Enum.filter(fn {n, _} -> is_binary(n) and String.starts_with?(n, prefix) end)
      |> Enum.map(&elem(&1, 1))
      |> Enum.sum()

  # The fraction of node-ticks down over the floor's run (up to its last task's end).
  defp down_fraction(r) do
    last_ms = if r.history == [], do: 0, else: (Experiment.span(r.history) |> elem(1)) - r.t0_us
    horizon = max(div(last_ms, 1000 * r.tick_ms), 1)
    nodes = r.schedule |> Enum.map(fn {_, {_, n}} -> n end) |> Enum.uniq()

    if nodes == [] do
      0.0
    else
      down_ticks =
        r.schedule
        |> Enum.group_by(fn {_, {_, n}} -> n end)
        |> Enum.map(fn {_, evs} ->
          evs
          |> Enum.map(fn {{:ms, t}, {what, _}} -> {div(t, r.tick_ms), what} end)
          |> Enum.chunk_every(2)
          |> Enum.map(fn
            [{d, :disconnect}, {u, :reconnect}] -> max(min(u, horizon) - min(d, horizon), 0)
            [{d, :disconnect}] -> max(horizon - d, 0)
          end)
          |> Enum.sum()
        end)
        |> Enum.sum()

      Float.round(down_ticks / (horizon * max(length(nodes), 1)), 3)
    end
  end

  @impl Experiment
  def record({c, seed}, state) do
    r = Enum.find(state.runs, &(&1.point == {c, seed}))
    Series.record(state.series, "jobs_done_p#{c}", seed, r.completed_jobs)
  end

  @impl Experiment
  def summary(base, state) do
    by_arm =
      state.runs
      |> Enum.group_by(&arm(&1.churn))
      |> Map.new(fn {arm, runs} ->
        ms = Enum.map(runs, &{to_string(&1.run_seed), measure(&1)})
        sum = fn key -> ms |> Enum.map(&elem(&1, 1)[key]) |> Enum.sum() end

        {arm,
         %{
           by_seed: Map.new(ms),
           violations: sum.(:violations),
           jobs: sum.(:jobs),
           done: sum.(:done),
           not_done_reported: sum.(:not_done_reported),
           disconnections_applied: sum.(:disconnections_applied),
           makespan_ms: ms |> Enum.map(&elem(&1, 1).makespan_ms) |> TartarusTools.Stats.median()
         }}
      end)

    Map.merge(base, %{
      speedup: nil,
      seeds: Experiment.seeds(%{seed: state.seed, seeds: state.p.seeds}),
      manet_robots: state.p.manet_robots,
      churn: state.p.churn,
      manet: by_arm
    })
  end

  @impl Experiment
  def gantt(%{kind: :manet, churn: c, run_seed: seed}, state) do
    if seed == state.seed and c == Enum.max(state.p.churn),
      do: {"robots and Σ nodes leaving and rejoining (p = #{c}), seed #{seed}", "gantt_manet.svg"}
  end

  def gantt(_run, _state), do: nil

  @impl Experiment
  def text(s),
    do:
      Enum.map_join(Enum.sort(s.manet), "\n", fn {arm, a} ->
        "#{arm}: #{a.done} of #{a.jobs} jobs done, #{a.not_done_reported} not done (reported), violations #{a.violations}, disconnections #{a.disconnections_applied}, median makespan #{a.makespan_ms} ms"
      end)
end
