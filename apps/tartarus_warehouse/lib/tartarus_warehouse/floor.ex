defmodule TartarusWarehouse.Floor do
  @moduledoc """
  A warehouse floor on the emulator: the network of §4.7.1 (robot nodes, secondary nodes
  that only relay agents, the distributor's node) started with `TartarusEmu.Network`, a
  robot plugin on each robot host and the distributor (or, for the baseline, the central
  server and its robot agents) created by the network's per-node setup hook. `run/1` feeds
  it jobs and returns what happened.

  ## Topology

  Node `"jd"` is the distributor's (the server's in the baseline); robots `"r1".."rk"` are
  linked to each other (a full mesh up to 16 robots, else a ring with chords to the robots
  4 and 16 places on) and to `"jd"` (the first 16); secondary nodes `"s1"..` hang on two
  robots each. Task agents move among robots (`TartarusWarehouse.Roam`).

  ## A floor you drive (iex)

  `run/1` runs a batch of jobs and returns when they are done. `start/1` starts a floor
  that stays up until `stop/1`: submit jobs when you like (`submit/2`), change it while it
  runs (`change/2`: insert or delete a task, retire a robot, let a standby robot join),
  look at it (`status/1`, or the web dashboard with `dashboard: port`), wait for the jobs
  (`await/2`), and `stop/1` it for what ran (as `run/1` reports it):

      iex> {:ok, f} = TartarusWarehouse.Floor.start(robots: 2, resources: [:rack, :bay])
      iex> TartarusWarehouse.Floor.submit(f, %{id: 1, tasks: [%{name: "T1", resources: [:rack]}]})
      :ok
      iex> {:error, _message} = TartarusWarehouse.Floor.submit(f, %{id: 2, tasks: [%{name: "T1", resources: [:dock]}]})
      iex> TartarusWarehouse.Floor.await(f, 10_000)
      :ok
      iex> {:ok, r} = TartarusWarehouse.Floor.stop(f)
      iex> {r.jobs, r.timed_out, r.mutex_violations}
      {[1], [], 0}
  """

  use GenServer

  alias TartarusEmu.{Network, Topology}
  alias TartarusTools.Dashboard.Panel
  alias TartarusWarehouse.{Checker, Job, Robot}

  @schema [
    robots: [type: :pos_integer, default: 4, doc: "robots"],
    secondary: [type: :non_neg_integer, default: 0, doc: "secondary (relay) nodes"],
    resources: [
      type: {:list, :any},
      default: [],
      doc: "the resources (default: those the jobs name)"
    ],
    reach: [
      type: :any,
      default: :all,
      doc: "`:all`, or a map robot index => resources it reaches"
    ],
    jobs: [type: {:list, :any}, default: [], doc: "job specs (see `TartarusWarehouse.Job`)"],
    arrivals_ms: [
      type: {:list, :non_neg_integer},
      default: [],
      doc: "arrival time of each job (default: all at once)"
    ],
    design: [
      type: {:in, [:agents, :central]},
      default: :agents,
      doc: "task agents, or the central server"
    ],
    scale: [type: :number, default: 0.01, doc: "time scale of task durations"],
    paces: [type: {:list, :number}, default: [], doc: "pace of robot i (default 1.0)"],
    jitter: [
      type: :number,
      default: 0.0,
      doc: "per-execution duration spread (0: equal durations)"
    ],
    idle_ms: [
      type: :non_neg_integer,
      default: 1,
      doc: "an agent that found no robot in a round waits this long"
    ],
    retire: [
      type: {:list, :any},
      default: [],
      doc:
        "`{robot_index, n}`: retire the robot once n jobs completed (the event `{n, {:retire, robot_index}}`)"
    ],
    events: [
      type: {:list, :any},
      default: [],
      doc:
        "`{n, event}`: once n jobs completed (0: right after the jobs are submitted), or `{{:ms, t}, event}`: t ms after the submission; `{:retire, i}` (robot i finishes its job and leaves; refused when no robot in service would be left, or none reaching a resource it reaches), `{:join, i}` (a standby robot joins), `{:insert, after_task, task_spec}`, `{:delete, task}` (on-the-fly programming); checked before the floor starts (`TartarusWarehouse.Job.change/2`)"
    ],
    standby: [
      type: {:list, :pos_integer},
      default: [],
      doc:
        "robots that start out of service (they join with `{:join, i}`); at least one robot starts in service"
    ],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    latency_ms: [
      type: :non_neg_integer,
      default: 0,
      doc:
        "one-way delay of every link (see `Tartarus.connect/3`: a hand-off pays three, a message between neighbours one each way; the central server's messages and the agents' migrations pay it alike)"
    ],
    server_ms: [
      type: :non_neg_integer,
      default: 0,
      doc:
        "`design: :central`: the server's time to handle one message from a robot (read it, update its tables, send the commands that follow); the server handles one message at a time, so messages queue behind it when robots report faster than it handles (see `TartarusWarehouse.Central`)"
    ],
    guide: [
      type: :boolean,
      default: false,
      doc:
        "agents climb a signal field to the robot that waits for them instead of searching blind (beyond the thesis; see `TartarusWarehouse.TaskAgent`)"
    ],
    failover: [
      type: :boolean,
      default: false,
      doc:
        "the distributor survives the loss of its host: its host journals (a fresh directory), task agents validate before running (see `TartarusWarehouse.DistributorAgent`); the event `{:kill_distributor, down_ms}` kills its host and starts it again"
    ],
    seed: [type: :integer, default: 1, doc: "seed"],
    status: [
      type: :any,
      default: nil,
      doc:
        "a public ETS table where the floor publishes itself while it runs, for the web dashboard (see `TartarusWarehouse.Panel`); nil: none"
    ],
    timeout_ms: [type: :pos_integer, default: 120_000, doc: "give up waiting after this long"]
  ]

  @doc "The options of `run/1`."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  The floor's topology for `robots` robots and `secondary` relay nodes.

      iex> t = TartarusWarehouse.Floor.topology(3, 2)
      iex> {length(t.nodes), TartarusEmu.Topology.connected?(t)}
      {6, true}
  """
  @spec topology(pos_integer(), non_neg_integer()) :: Topology.t()
  def topology(robots, secondary) do
    rs = Enum.map(1..robots, &"r#{&1}")
    ss = if secondary > 0, do: Enum.map(1..secondary, &"s#{&1}"), else: []

    robot_edges = robot_edges(robots)
    jd_edges = for i <- 1..min(robots, 16), do: {"jd", "r#{i}"}

    s_edges =
      for {s, i} <- Enum.with_index(ss),
          r <- Enum.uniq([rem(i, robots) + 1, rem(i + 1, robots) + 1]),
          do: {s, "r#{r}"}

    Topology.new(["jd" | rs] ++ ss, Enum.uniq(robot_edges ++ jd_edges ++ s_edges))
  end

  # Robots: a full mesh up to 16, else a ring with chords 4 and 16 places on (modulo the
  # robots: a circulant graph, the same seen from every robot).
  defp robot_edges(robots) do
    if robots <= 16,
      do: for(i <- 1..robots, j <- (i + 1)..robots//1, do: {"r#{i}", "r#{j}"}),
      else:
        for(
          i <- 1..robots,
          d <- [1, 4, 16],
          j = rem(i - 1 + d, robots) + 1,
          j != i,
          do: {"r#{min(i, j)}", "r#{max(i, j)}"}
        )
  end

  @doc """
  Runs jobs on a floor. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, result}` with `history` (every execution: see
  `TartarusWarehouse.Robot`), `jobs` (ids in submission order), `completed` (id =>
  completion time, µs), `t0_us` (submission of the first job), `makespan_ms`, `robots`,
  `migrations`, `bytes`, `messages` (from `TartarusEmu.Log`), `timed_out` (jobs not done),
  `refused_events` (events that were refused and changed nothing, with the reason),
  `failed` (nil, or why the distributor failed: its jobs are then lost and `run/1` stops
  waiting for them),
  `applied_events` (events applied, each with the time it took effect, µs),
  `wall_ms`; or `{:error, message}` for bad options or a rejected job.
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusWarehouse.Floor.run/1"),
         :ok <- check_standby(opts, "run/1"),
         world = world(opts),
         :ok <- plan_all(opts[:jobs], world),
         :ok <- check_events(events(opts), world, opts[:robots]) do
      start_and_run(world, opts)
    end
  end

  # At least one robot starts in service, and standby robots are robots of the floor.
  defp check_standby(opts, fun) do
    robots = opts[:robots]

    cond do
      Enum.any?(opts[:standby], &(&1 > robots)) ->
        {:error,
         "invalid options given to TartarusWarehouse.Floor.#{fun} for key :standby: expected indices of robots 1..#{robots}, got: #{inspect(opts[:standby])}"}

      Enum.all?(1..robots, &(&1 in opts[:standby])) ->
        {:error,
         "invalid options given to TartarusWarehouse.Floor.#{fun} for key :standby: at least one robot must start in service (a floor with none would take jobs it cannot run), got: #{inspect(opts[:standby])}"}

      true ->
        :ok
    end
  end

  # `run/1`'s events (and `retire`), checked before anything starts: when each fires, and
  # what it is (`TartarusWarehouse.Job.change/2`), with robots of this floor.
  defp check_events(events, world, robots) do
    Enum.find_value(events, :ok, fn
      {:retire_option, other} ->
        {:error,
         "invalid options given to TartarusWarehouse.Floor.run/1 for key :retire: expected {robot_index, n}, got: #{inspect(other, limit: 5)}"}

      {n, event} when (is_integer(n) and n >= 0) or (is_tuple(n) and tuple_size(n) == 2) ->
        with :ok <- check_when(n),
             {:ok, event} <- Job.change(event, world),
             :ok <- check_robot(event, robots) do
          nil
        end

      other ->
        {:error,
         "invalid options given to TartarusWarehouse.Floor.run/1 for key :events: expected {n, event} or {{:ms, t}, event}, got: #{inspect(other, limit: 5)}"}
    end)
  end

  defp check_when({:ms, t}) when is_integer(t) and t >= 0, do: :ok
  defp check_when(n) when is_integer(n) and n >= 0, do: :ok

  defp check_when(other),
    do:
      {:error,
       "invalid options given to TartarusWarehouse.Floor.run/1 for key :events: expected when an event fires to be n (jobs completed) or {:ms, t}, got: #{inspect(other)}"}

  defp check_robot({what, i}, robots) when what in [:retire, :join] and i > robots,
    do: {:error, "no robot #{inspect(i)} (the floor has robots 1..#{robots})"}

  defp check_robot(_event, _robots), do: :ok

  defp world(opts) do
    resources =
      case opts[:resources] do
        [] ->
          # Those of well-formed tasks: a malformed job is named by plan_all/2.
          for %{tasks: tasks} when is_list(tasks) <- opts[:jobs],
              %{resources: rs} when is_list(rs) <- tasks,
              r <- rs,
              uniq: true,
              do: r

        rs ->
          rs
      end

    reach =
      case opts[:reach] do
        :all -> opts[:robots]
        map -> Map.new(1..opts[:robots], &{&1, Map.get(map, &1, [])})
      end

    world = Job.world(resources, reach)
    %{world | robots: Map.new(world.robots, fn {i, r} -> {"r#{i}", r} end)}
  end

  defp plan_all(jobs, world) do
    Enum.find_value(jobs, :ok, fn spec ->
      case Job.plan(spec, world) do
        {:ok, _} -> nil
        {:error, m} -> {:error, m}
      end
    end)
  end

  defp start_and_run(world, opts) do
    t_start = System.monotonic_time(:millisecond)
    ctx = start_floor(world, opts, self())

    try do
      t0 = System.system_time(:microsecond)
      publish_floor(ctx, length(opts[:jobs]), t0)
      submit(ctx.dref, opts[:jobs], opts[:arrivals_ms])
      events = events(opts)
      fire(events, 0, ctx)
      completed = await(opts, events, ctx, %{}, length(opts[:jobs]), t0)

      {:ok,
       ctx
       |> collect(Enum.map(opts[:jobs], & &1.id), completed, t0)
       |> Map.merge(%{
         refused_events: refused(),
         failed: failed(),
         applied_events: applied(),
         killed_at_us: killed(),
         wall_ms: System.monotonic_time(:millisecond) - t_start
       })}
    after
      stop_floor(ctx)
    end
  end

  # Starts the floor's network, robots and distributor (or central server); `owner` gets
  # `{:warehouse_job_done, id, at_us}` for every job completed.
  defp start_floor(world, opts, owner) do
    robots = opts[:robots]

    setup = fn node, host ->
      case node do
        "r" <> i ->
          i = String.to_integer(i)

          :ok =
            Tartarus.attach_plugin(
              host,
              :robot,
              {Robot,
               robot: node,
               reach: if(opts[:reach] == :all, do: :all, else: Map.get(opts[:reach], i, [])),
               scale: opts[:scale],
               pace: Enum.at(opts[:paces], i - 1, 1.0),
               jitter: opts[:jitter],
               seed: opts[:seed],
               off: i in opts[:standby]}
            )

          :ok

        _ ->
          :ok
      end
    end

    data_dir =
      if opts[:failover],
        do: Path.join(System.tmp_dir!(), "warehouse-jd-#{System.unique_integer([:positive])}")

    node_opts = if data_dir, do: %{"jd" => [data_dir: data_dir]}, else: %{}

    {:ok, net} =
      Network.start(topology(robots, opts[:secondary]),
        mode: opts[:mode],
        setup: setup,
        node_opts: node_opts,
        link: [latency_ms: opts[:latency_ms]]
      )

    try do
      start_agents(net, world, opts, owner, data_dir)
    rescue
      e ->
        Network.stop(net)
        if data_dir, do: File.rm_rf(data_dir)
        reraise e, __STACKTRACE__
    end
  end

  defp start_agents(net, world, opts, owner, data_dir) do
    robots = opts[:robots]
    design = opts[:design]
    {:ok, log} = TartarusEmu.Log.start(net)
    robot_hosts = for i <- 1..robots, into: %{}, do: {"r#{i}", Network.host(net, "r#{i}")}
    jd = Network.host(net, "jd")

    {:ok, dist} =
      case design do
        :agents ->
          Tartarus.create_static_agent(
            jd,
            TartarusWarehouse.DistributorAgent,
            %{
              world: world,
              owner: owner,
              robots: robot_set(robot_hosts),
              all_robots: MapSet.new(Map.values(robot_hosts)),
              idle_ms: opts[:idle_ms],
              round: min(robots, 16),
              seed: opts[:seed],
              validate: opts[:failover],
              guide: if(opts[:guide], do: robot_span(robots))
            },
            # told `{:tartarus_removed, id, reason}` if it is removed
            owner: owner
          )

        :central ->
          agents =
            Map.new(robot_hosts, fn {name, host} ->
              {:ok, id} =
                Tartarus.create_static_agent(host, TartarusWarehouse.CentralRobot, %{
                  robot: name,
                  server: nil
                })

              {name, {id, host}}
            end)

          {:ok, sid} =
            Tartarus.create_static_agent(
              jd,
              TartarusWarehouse.Central,
              %{world: world, owner: owner, robots: agents, server_ms: opts[:server_ms]},
              owner: owner
            )

          Enum.each(agents, fn {_, a} -> :ok = Tartarus.post(a, {:server, {sid, jd}}) end)
          {:ok, sid}
      end

    %{
      dref: {dist, jd},
      robot_hosts: robot_hosts,
      net: net,
      log: log,
      status: opts[:status],
      design: design,
      guide: opts[:guide],
      failover: opts[:failover],
      data_dir: data_dir,
      world: world
    }
  end

  defp publish_floor(ctx, jobs, t0) do
    Panel.publish(ctx.status, fn t ->
      :ets.insert(t, [
        {:floor,
         %{
           net: ctx.net,
           robot_hosts: ctx.robot_hosts,
           design: ctx.design,
           guide: ctx.guide,
           t0_us: t0
         }},
        {:jobs, jobs, 0}
      ])
    end)
  end

  # What ran: the robots' histories (the event log), completions, the network's totals.
  defp collect(ctx, ids, completed, t0) do
    :ok = TartarusEmu.Log.sync(ctx.log)
    totals = TartarusEmu.Log.totals(ctx.log)

    history = Robot.history(ctx.robot_hosts)

    last = completed |> Map.values() |> Enum.max(fn -> t0 end)

    %{
      design: ctx.design,
      history: history,
      jobs: ids,
      completed: completed,
      timed_out: Enum.reject(ids, &Map.has_key?(completed, &1)),
      t0_us: t0,
      makespan_ms: (last - t0) / 1000,
      robots:
        Map.keys(ctx.robot_hosts)
        |> Enum.sort_by(&String.to_integer(String.slice(&1, 1..-1//1))),
      migrations: Map.get(totals, :departures, 0),
      bytes: Map.get(totals, :bytes, 0),
      messages: Map.get(totals, :messages, 0)
    }
  end

  defp stop_floor(ctx) do
    Panel.publish(ctx.status, &:ets.delete(&1, :floor))
    TartarusEmu.Log.stop(ctx.log)
    Network.stop(ctx.net)
    if ctx.data_dir, do: File.rm_rf(ctx.data_dir)
  end

  # How agents tell robots: by name prefix ("emu<tag>-r"), when every robot's name has it
  # (nothing that grows with the robots travels with them), else the set of robot hosts.
  defp robot_set(robot_hosts) do
    {name, _} = robot_hosts["r1"]

    with true <- is_binary(name) and String.ends_with?(name, "-r1"),
         prefix = String.slice(name, 0..-2//1),
         true <-
           Enum.all?(robot_hosts, fn {r, {n, _}} -> n == prefix <> String.slice(r, 1..-1//1) end) do
      {:prefix, prefix}
    else
      _ -> MapSet.new(Map.values(robot_hosts))
    end
  end

  # The hops between the two farthest robots (a full mesh: 1).
  defp robot_span(robots) when robots <= 16, do: 1

  # How far a field must reach to cover every robot from any robot: the diameter of the
  # robots' own graph (circulant, so any robot's eccentricity; the other hosts only add
  # shortcuts, never length).
  defp robot_span(robots) do
    robot_topo = Topology.new(Enum.map(1..robots, &"r#{&1}"), robot_edges(robots))
    robot_topo |> Topology.distances("r1") |> Map.values() |> Enum.max()
  end

  defp submit(dref, jobs, arrivals) do
    if arrivals == [] do
      Enum.each(jobs, &submit_one!(dref, &1))
    else
      t0 = System.monotonic_time(:millisecond)

      jobs
      |> Enum.zip(
        arrivals ++ List.duplicate(List.last(arrivals), max(length(jobs) - length(arrivals), 0))
      )
      |> Enum.sort_by(&elem(&1, 1))
      |> Enum.each(fn {job, at} ->
        wait = at - (System.monotonic_time(:millisecond) - t0)
        if wait > 0, do: Process.sleep(wait)
        submit_one!(dref, job)
      end)
    end
  end

  # Asked again while the distributor is unreachable (its host restarting), for 30 s.
  defp submit_one(dref, job, tries \\ 3000) do
    case Tartarus.request(dref, {:submit, job}, 5_000) do
      {:ok, :ok} ->
        :ok

      {:error, _} when tries > 0 ->
        Process.sleep(10)
        submit_one(dref, job, tries - 1)

      other ->
        {:error, "job #{inspect(job.id)} was refused: #{inspect(other)}"}
    end
  end

  defp submit_one!(dref, job) do
    with {:error, message} <- submit_one(dref, job), do: raise(message)
  end

  # Waits for the jobs, firing the events due: `{n, e}` once n jobs completed, `{{:ms, t}, e}`
  # t ms after the submission.
  defp await(opts, events, ctx, done, total, t0) do
    now_ms = div(System.system_time(:microsecond) - t0, 1000)
    {due, events} = Enum.split_with(events, &match?({{:ms, t}, _} when t <= now_ms, &1))
    Enum.each(due, fn {_, e} -> fire_one(e, ctx) end)

    next =
      events
      |> Enum.flat_map(fn
        {{:ms, t}, _} -> [t - now_ms]
        _ -> []
      end)
      |> Enum.min(fn -> opts[:timeout_ms] end)

    cond do
      map_size(done) >= total ->
        done

      now_ms > opts[:timeout_ms] ->
        done

      true ->
        receive do
          {:warehouse_job_done, id, at} ->
            done = Map.put(done, id, at)
            Panel.publish(ctx.status, &:ets.update_element(&1, :jobs, {3, map_size(done)}))
            fire(events, map_size(done), ctx)
            await(opts, events, ctx, done, total, t0)

          # The distributor failed: the jobs it held will not complete; no use waiting.
          {:warehouse_distributor_failed, reason} ->
            send(self(), {:warehouse_failed, reason})
            done

          {:tartarus_removed, id, reason} when id == elem(ctx.dref, 0) ->
            send(self(), {:warehouse_failed, "the distributor was removed: #{inspect(reason)}"})
            done
        after
          max(min(next, opts[:timeout_ms]), 0) ->
            await(opts, events, ctx, done, total, t0)
        end
    end
  end

  defp events(opts) do
    retire =
      Enum.map(opts[:retire], fn
        {i, n} -> {n, {:retire, i}}
        other -> {:retire_option, other}
      end)

    retire ++ opts[:events]
  end

  defp fire(events, count, ctx) do
    for {^count, event} <- events, do: fire_one(event, ctx)
    :ok
  end

  # A change the floor refuses (an unknown robot, a task already inserted, ...) changes
  # nothing; it is reported in the result's `refused_events`.
  defp fire_one(event, ctx) do
    case apply_event(event, ctx) do
      :ok -> send(self(), {:warehouse_applied, event, System.system_time(:microsecond)})
      {:error, reason} -> send(self(), {:warehouse_refused, event, reason})
    end

    :ok
  end

  defp apply_event({:insert, _, _}, %{design: :central}),
    do: {:error, "the central baseline takes no on-the-fly changes"}

  defp apply_event({:delete, _}, %{design: :central}),
    do: {:error, "the central baseline takes no on-the-fly changes"}

  # Every change is checked first (`Job.change/2`: the one door for changes); a malformed
  # one never reaches the distributor or a robot.
  defp apply_event(event, ctx) do
    case Job.change(event, ctx.world) do
      {:ok, event} -> apply_valid(event, ctx)
      {:error, message} -> {:error, message}
    end
  end

  defp apply_valid(event, %{dref: dref, robot_hosts: robot_hosts, net: net} = ctx) do
    result =
      case event do
        {:retire, i} -> retire(ctx, i)
        {:join, i} -> plugin(robot_hosts, i, :join)
        {:insert, after_task, task} -> Tartarus.request(dref, {:insert, after_task, task}, 30_000)
        {:delete, task} -> Tartarus.request(dref, {:delete, task}, 30_000)
        {:kill_distributor, down_ms} -> kill_distributor(net, down_ms)
      end

    case result do
      ok when ok in [:ok, {:ok, :ok}] -> :ok
      {:ok, {:error, reason}} -> {:error, reason}
      {:error, :timeout} -> {:error, "the distributor did not answer within 30 s"}
      {:error, reason} when is_binary(reason) -> {:error, reason}
      {:error, reason} -> {:error, "#{inspect(event)} failed: #{inspect(reason)}"}
    end
  end

  # A robot may leave only if the robots still in service (not off, not retiring) reach
  # every resource it reaches: the floor never takes jobs it has no robot for, and no task
  # agent searches for a robot that will not come back.
  defp retire(ctx, i) do
    name = "r#{i}"

    with {:ok, host} <- robot_host(ctx.robot_hosts, i),
         {:ok, states} <- robot_states(ctx.robot_hosts),
         :ok <- still_served(ctx.world, states, name) do
      Tartarus.write_plugin(host, :robot, :retire)
    end
  end

  defp still_served(world, states, name) do
    in_service = fn r -> match?(%{off: false, retiring: false}, states[r]) end

    if in_service.(name) do
      others = for {r, reach} <- world.robots, r != name, in_service.(r), do: reach

      lost =
        MapSet.difference(world.robots[name], Enum.reduce(others, MapSet.new(), &MapSet.union/2))

      cond do
        others == [] ->
          {:error,
           "robot #{String.slice(name, 1..-1//1)} is the last robot in service: retiring it would leave the floor no robot to run jobs (let a standby robot join first)"}

        MapSet.size(lost) > 0 ->
          {:error,
           "robot #{String.slice(name, 1..-1//1)} is the last robot in service that reaches #{lost |> Enum.sort() |> Enum.map_join(", ", &inspect/1)}: retiring it would leave jobs that need it no robot"}

        true ->
          :ok
      end
    else
      # Already off or leaving: retiring it again changes nothing.
      :ok
    end
  end

  defp robot_states(robot_hosts) do
    Enum.reduce_while(robot_hosts, {:ok, %{}}, fn {name, host}, {:ok, acc} ->
      case Tartarus.read_plugin(host, :robot, :state) do
        {:ok, state} ->
          {:cont, {:ok, Map.put(acc, name, state)}}

        {:error, reason} ->
          {:halt,
           {:error, "robot #{name} could not be read (#{inspect(reason)}): nothing retired"}}
      end
    end)
  end

  # The distributor's host dies with everything on it, and starts again `down_ms` later
  # (on its journal, with `failover: true`).
  defp kill_distributor(net, down_ms) do
    :ok = Network.kill_node(net, "jd")
    send(self(), {:warehouse_killed, System.system_time(:microsecond)})
    Process.sleep(down_ms)
    Network.restart_node(net, "jd")
  end

  defp plugin(robot_hosts, i, what) do
    with {:ok, host} <- robot_host(robot_hosts, i), do: Tartarus.write_plugin(host, :robot, what)
  end

  defp robot_host(robot_hosts, i) do
    case Map.fetch(robot_hosts, "r#{i}") do
      {:ok, host} -> {:ok, host}
      :error -> {:error, "no robot #{inspect(i)}"}
    end
  end

  defp killed do
    receive do
      {:warehouse_killed, at} -> [at | killed()]
    after
      0 -> []
    end
  end

  defp applied do
    receive do
      {:warehouse_applied, event, at} -> [%{event: event, at_us: at} | applied()]
    after
      0 -> []
    end
  end

  defp failed do
    receive do
      {:warehouse_failed, reason} -> reason
    after
      0 -> nil
    end
  end

  defp refused do
    receive do
      {:warehouse_refused, event, reason} -> [%{event: event, reason: reason} | refused()]
    after
      0 -> []
    end
  end

  # -- a floor you drive ---------------------------------------------------------------

  @start_extra [
    dashboard: [
      type: :any,
      default: nil,
      doc:
        "serve the web dashboard on this port (127.0.0.1), or dashboard options (`port:`, `token:`, ... of `TartarusTools.Dashboard`): the floor's hosts and the warehouse panel (`TartarusWarehouse.Panel`); nil: none"
    ]
  ]

  @doc """
  Starts a floor that stays up until `stop/1` (not linked to the caller). Options: those of
  `run/1` (the `jobs` given are submitted at once; `events`, `retire`, `arrivals_ms` and
  `timeout_ms` are for `run/1`: here, call `change/2`), and `dashboard`. Give `resources`
  for jobs to come (by default the floor knows the resources its first jobs name).
  Returns `{:ok, floor}` or `{:error, message}`.
  """
  @spec start(keyword()) :: {:ok, pid()} | {:error, String.t()}
  def start(opts \\ []) do
    with {:ok, opts} <-
           Tartarus.Options.validate(
             opts,
             @schema ++ @start_extra,
             "TartarusWarehouse.Floor.start/1"
           ),
         :ok <- check_standby(opts, "start/1"),
         world = world(opts),
         :ok <- plan_all(opts[:jobs], world) do
      case GenServer.start(__MODULE__, {world, opts}) do
        {:ok, pid} -> {:ok, pid}
        {:error, {:dashboard, message}} -> {:error, message}
        {:error, reason} -> {:error, "the floor did not start: #{inspect(reason)}"}
      end
    end
  end

  @doc """
  Submits a job (a job spec, see `TartarusWarehouse.Job`) to a started floor: `:ok`, or
  `{:error, message}` for a malformed job (checked by `TartarusWarehouse.Job.plan/2`: the
  message names the field, what was expected and what arrived), an id already submitted,
  or a floor that failed (see `status/1`); nothing changes then.
  """
  @spec submit(pid(), map()) :: :ok | {:error, String.t()}
  def submit(floor, job), do: GenServer.call(floor, {:submit, job}, 60_000)

  @doc """
  Changes a started floor while it runs: `{:insert, after_task, task_spec}`,
  `{:delete, task}`, `{:retire, i}`, `{:join, i}` or `{:kill_distributor, down_ms}` (see
  `run/1`'s `events`; the kill needs a floor started with `failover: true`, and the floor
  answers nothing else until its distributor's host is back). `:ok`, or `{:error, message}`
  when refused, and nothing changes: a malformed change (checked by
  `TartarusWarehouse.Job.change/2` before anything is asked of the distributor or a
  robot), an unknown robot, a robot whose retirement would leave no robot in service (or
  none in service reaching a resource it reaches: the floor would take jobs it cannot
  run), a task already inserted, or a floor that failed.
  """
  @spec change(pid(), term()) :: :ok | {:error, String.t()}
  def change(floor, event) do
    down_ms =
      case event do
        {:kill_distributor, ms} when is_integer(ms) and ms >= 0 -> ms
        _ -> 0
      end

    GenServer.call(floor, {:change, event}, 60_000 + down_ms)
  end

  @doc """
  What a started floor is doing: `jobs` (ids, in submission order), `done` (ids
  completed), `pending`, `robots` (name => the robot's state, see
  `TartarusWarehouse.Robot`), `hosts` (name => host), `elapsed_ms`, `failed` (nil, or why
  the floor failed: its distributor crashed and lost its jobs, or was removed; the floor
  then takes no more jobs or changes, and `stop/1` still reports what ran) and `errors`
  (oldest first: requests the floor or the distributor could not handle, each answered
  `{:error, message}` to its caller, and the failure).
  """
  @spec status(pid()) :: map()
  def status(floor), do: GenServer.call(floor, :status, 30_000)

  @doc """
  Waits until every job submitted so far completed: `:ok`, `{:error, :timeout}`,
  `{:error, :stopped}` when the floor is stopped meanwhile, or `{:error, message}` when
  the floor failed (at once, or as soon as it fails: see `status/1`).
  """
  @spec await(pid(), timeout()) :: :ok | {:error, :timeout | :stopped | String.t()}
  def await(floor, timeout \\ 60_000) do
    GenServer.call(floor, {:await, timeout}, :infinity)
  end

  @doc """
  Stops a started floor and returns `{:ok, result}`: the keys of `run/1`'s result that
  describe what ran (`history`, `jobs`, `completed`, `timed_out`: the jobs not completed
  when it stopped, `t0_us`, `makespan_ms`, `robots`, `migrations`, `bytes`, `messages`),
  with `mutex_violations` (Eq. 4.1, pairs of executions:
  `TartarusWarehouse.Checker.violations/1`) and `changes` (every `change/2`, with its time
  and its result, `:ok` or `{:error, reason}`) instead of `run/1`'s event lists.
  """
  @spec stop(pid()) :: {:ok, map()}
  def stop(floor), do: GenServer.call(floor, :stop, 60_000)

  @impl GenServer
  def init({world, opts}) do
    Process.flag(:trap_exit, true)
    table = TartarusWarehouse.Panel.new()
    ctx = start_floor(world, Keyword.put(opts, :status, table), self())
    t0 = System.system_time(:microsecond)
    publish_floor(ctx, 0, t0)

    case start_dashboard(opts[:dashboard], ctx, table) do
      {:ok, dash} ->
        st = %{
          ctx: ctx,
          t0: t0,
          jobs: [],
          done: %{},
          waiters: [],
          dash: dash,
          changes: [],
          failed: nil,
          errors: []
        }

        {:ok, Enum.reduce(opts[:jobs], st, &elem(do_submit(&1, &2), 1))}

      {:error, message} ->
        stop_floor(ctx)
        {:stop, {:dashboard, message}}
    end
  end

  defp start_dashboard(nil, _ctx, _table), do: {:ok, nil}

  # Linked once started: it goes with the floor.
  defp start_dashboard(spec, ctx, table) do
    with {:ok, dash} <-
           TartarusEmu.Dashboard.serve(ctx.net, spec, [{TartarusWarehouse.Panel, table}]) do
      Process.link(dash)
      {:ok, dash}
    end
  end

  @impl GenServer
  def handle_call({what, _}, _from, %{failed: reason} = st)
      when reason != nil and what in [:submit, :change] do
    {:reply, {:error, failed_message(reason)}, st}
  end

  def handle_call({:submit, job}, _from, st) do
    {reply, st} = guarded(st, "submit #{inspect(job, limit: 5)}", &do_submit(job, &1))
    {:reply, reply, st}
  end

  def handle_call({:change, event}, _from, st) do
    {result, st} =
      guarded(st, "change #{inspect(event, limit: 5)}", fn st ->
        result =
          case event do
            {:kill_distributor, _} when not st.ctx.failover ->
              {:error,
               "the distributor's host can be killed only on a floor started with failover: true (without it every job stops)"}

            _ ->
              apply_event(event, st.ctx)
          end

        {result, st}
      end)

    change = %{event: event, at_us: System.system_time(:microsecond), result: result}
    {:reply, result, %{st | changes: [change | st.changes]}}
  end

  def handle_call(:status, _from, st) do
    robots =
      Map.new(st.ctx.robot_hosts, fn {name, host} ->
        case Tartarus.read_plugin(host, :robot, :state) do
          {:ok, state} -> {name, state}
          {:error, reason} -> {name, {:unreachable, reason}}
        end
      end)

    {:reply,
     %{
       jobs: st.jobs,
       done: Enum.filter(st.jobs, &Map.has_key?(st.done, &1)),
       pending: Enum.reject(st.jobs, &Map.has_key?(st.done, &1)),
       robots: robots,
       hosts: st.ctx.robot_hosts,
       elapsed_ms: div(System.system_time(:microsecond) - st.t0, 1000),
       failed: st.failed,
       errors: Enum.reverse(st.errors)
     }, st}
  end

  def handle_call({:await, timeout}, from, st) do
    cond do
      all_done?(st) -> {:reply, :ok, st}
      st.failed -> {:reply, {:error, failed_message(st.failed)}, st}
      true -> wait(timeout, from, st)
    end
  end

  def handle_call(:stop, from, st), do: stop_call(from, st)

  defp wait(timeout, from, st) do
    ref = make_ref()
    if timeout != :infinity, do: Process.send_after(self(), {:await_timeout, ref}, timeout)
    {:noreply, %{st | waiters: [{ref, from} | st.waiters]}}
  end

  defp stop_call(_from, st) do
    result = collect(st.ctx, st.jobs, st.done, st.t0)

    result =
      Map.merge(result, %{
        mutex_violations: length(Checker.violations(result.history)),
        changes: Enum.reverse(st.changes)
      })

    Enum.each(st.waiters, fn {_, from} -> GenServer.reply(from, {:error, :stopped}) end)
    # Everything is stopped before the caller hears back.
    shut_down(st)
    {:stop, :normal, {:ok, result}, %{st | waiters: [], dash: nil, ctx: nil}}
  end

  @impl GenServer
  def handle_info({:warehouse_job_done, id, at}, st) do
    st = %{st | done: Map.put(st.done, id, at)}
    Panel.publish(st.ctx.status, &:ets.update_element(&1, :jobs, {3, map_size(st.done)}))

    if all_done?(st) do
      Enum.each(st.waiters, fn {_, from} -> GenServer.reply(from, :ok) end)
      {:noreply, %{st | waiters: []}}
    else
      {:noreply, st}
    end
  end

  def handle_info({:await_timeout, ref}, st) do
    case List.keytake(st.waiters, ref, 0) do
      {{^ref, from}, rest} ->
        GenServer.reply(from, {:error, :timeout})
        {:noreply, %{st | waiters: rest}}

      nil ->
        {:noreply, st}
    end
  end

  # The distributor (or the central server) failed: every job it held is lost. The floor
  # says so (status/1's `failed`), answers its waiters, and takes no more jobs or changes.
  def handle_info({:warehouse_distributor_failed, reason}, st), do: {:noreply, fail(st, reason)}

  def handle_info({:tartarus_removed, id, reason}, %{ctx: %{dref: {id, _}}} = st),
    do: {:noreply, fail(st, "the distributor was removed: #{inspect(reason, limit: 5)}")}

  # A request the distributor could not handle (answered with an error, nothing changed).
  def handle_info({:warehouse_distributor_error, message}, st),
    do: {:noreply, %{st | errors: [message | st.errors]}}

  def handle_info({:EXIT, dash, _reason}, %{dash: dash} = st), do: {:noreply, %{st | dash: nil}}
  def handle_info(_other, st), do: {:noreply, st}

  @impl GenServer
  def terminate(_reason, st), do: shut_down(st)

  defp shut_down(st) do
    if st.dash do
      try do
        TartarusTools.Dashboard.stop(st.dash)
      catch
        :exit, _ -> :ok
      end
    end

    if st.ctx, do: stop_floor(st.ctx)
  end

  defp do_submit(job, st) do
    with {:ok, _} <- Job.plan(job, st.ctx.world),
         false <- job.id in st.jobs,
         :ok <- submit_one(st.ctx.dref, job) do
      st = %{st | jobs: st.jobs ++ [job.id]}
      Panel.publish(st.ctx.status, &:ets.update_element(&1, :jobs, {2, length(st.jobs)}))
      {:ok, st}
    else
      {:error, message} -> {{:error, message}, st}
      true -> {{:error, "job #{inspect(job.id)} was already submitted"}, st}
    end
  end

  defp all_done?(st), do: Enum.all?(st.jobs, &Map.has_key?(st.done, &1))

  defp fail(%{failed: nil} = st, reason) do
    Enum.each(st.waiters, fn {_, from} ->
      GenServer.reply(from, {:error, failed_message(reason)})
    end)

    %{st | failed: reason, waiters: [], errors: [reason | st.errors]}
  end

  defp fail(st, _reason), do: st

  defp failed_message(reason),
    do: "the floor failed (#{reason}): it takes no more jobs or changes; stop/1 it for what ran"

  # An exception while the floor handles a request is the caller's answer, `{:error,
  # message}`, and is kept in status/1's `errors`; the floor goes on, unchanged.
  defp guarded(st, what, fun) do
    fun.(st)
  catch
    kind, reason ->
      message =
        "the floor could not #{what}: " <> Exception.format_banner(kind, reason, __STACKTRACE__)

      {{:error, message}, %{st | errors: [message | st.errors]}}
  end
end
