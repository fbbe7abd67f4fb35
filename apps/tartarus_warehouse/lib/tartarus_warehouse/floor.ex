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
  """

  alias TartarusEmu.{Network, Topology}
  alias TartarusWarehouse.{Job, Robot}

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
      doc: "`{robot_index, after_job_done_count}`: retire the robot once that many jobs completed"
    ],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    seed: [type: :integer, default: 1, doc: "seed"],
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

    robot_edges =
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

    jd_edges = for i <- 1..min(robots, 16), do: {"jd", "r#{i}"}

    s_edges =
      for {s, i} <- Enum.with_index(ss),
          r <- Enum.uniq([rem(i, robots) + 1, rem(i + 1, robots) + 1]),
          do: {s, "r#{r}"}

    Topology.new(["jd" | rs] ++ ss, Enum.uniq(robot_edges ++ jd_edges ++ s_edges))
  end

  @doc """
  Runs jobs on a floor. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, result}` with `history` (every execution: see
  `TartarusWarehouse.Robot`), `jobs` (ids in submission order), `completed` (id =>
  completion time, µs), `t0_us` (submission of the first job), `makespan_ms`, `robots`,
  `migrations`, `bytes`, `messages` (from `TartarusEmu.Log`), `timed_out` (jobs not done),
  `wall_ms`; or `{:error, message}` for bad options or a rejected job.
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusWarehouse.Floor.run/1") do
      resources =
        case opts[:resources] do
          [] ->
            opts[:jobs]
            |> Enum.flat_map(&Enum.flat_map(&1.tasks, fn t -> t.resources end))
            |> Enum.uniq()

          rs ->
            rs
        end

      reach =
        case opts[:reach] do
          :all -> opts[:robots]
          map -> Map.new(1..opts[:robots], &{&1, Map.get(map, &1, [])})
        end

      world = Job.world(resources, reach)
      world = %{world | robots: Map.new(world.robots, fn {i, r} -> {"r#{i}", r} end)}
      with_world(world, opts)
    end
  end

  defp with_world(world, opts) do
    Enum.find_value(opts[:jobs], fn spec ->
      case Job.plan(spec, world) do
        {:ok, _} -> nil
        {:error, m} -> {:error, m}
      end
    end) || start_and_run(world, opts)
  end

  defp start_and_run(world, opts) do
    owner = self()
    robots = opts[:robots]
    design = opts[:design]
    t_start = System.monotonic_time(:millisecond)

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
               seed: opts[:seed]}
            )

          :ok

        _ ->
          :ok
      end
    end

    {:ok, net} =
      Network.start(topology(robots, opts[:secondary]), mode: opts[:mode], setup: setup)

    try do
      {:ok, log} = TartarusEmu.Log.start(net)
      robot_hosts = for i <- 1..robots, into: %{}, do: {"r#{i}", Network.host(net, "r#{i}")}
      jd = Network.host(net, "jd")

      {:ok, dist} =
        case design do
          :agents ->
            Tartarus.create_static_agent(jd, TartarusWarehouse.DistributorAgent, %{
              world: world,
              owner: owner,
              robots: MapSet.new(Map.values(robot_hosts)),
              idle_ms: opts[:idle_ms],
              round: min(robots, 16),
              seed: opts[:seed]
            })

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
              Tartarus.create_static_agent(jd, TartarusWarehouse.Central, %{
                world: world,
                owner: owner,
                robots: agents
              })

            Enum.each(agents, fn {_, a} -> :ok = Tartarus.post(a, {:server, {sid, jd}}) end)
            {:ok, sid}
        end

      dref = {dist, jd}
      t0 = System.system_time(:microsecond)
      submit(dref, opts[:jobs], opts[:arrivals_ms])
      completed = await(opts, robot_hosts, %{}, length(opts[:jobs]), t0)
      :ok = TartarusEmu.Log.sync(log)
      totals = TartarusEmu.Log.totals(log)
      TartarusEmu.Log.stop(log)

      history =
        robot_hosts
        |> Enum.flat_map(fn {_, h} ->
          case Tartarus.read_plugin(h, :robot, :history) do
            {:ok, list} -> list
            _ -> []
          end
        end)
        |> Enum.sort_by(& &1.start_us)

      ids = Enum.map(opts[:jobs], & &1.id)
      last = completed |> Map.values() |> Enum.max(fn -> t0 end)

      {:ok,
       %{
         design: design,
         history: history,
         jobs: ids,
         completed: completed,
         timed_out: Enum.reject(ids, &Map.has_key?(completed, &1)),
         t0_us: t0,
         makespan_ms: (last - t0) / 1000,
         robots:
           Map.keys(robot_hosts) |> Enum.sort_by(&String.to_integer(String.slice(&1, 1..-1//1))),
         migrations: Map.get(totals, :departures, 0),
         bytes: Map.get(totals, :bytes, 0),
         messages: Map.get(totals, :messages, 0),
         wall_ms: System.monotonic_time(:millisecond) - t_start
       }}
    after
      Network.stop(net)
    end
  end

  defp submit(dref, jobs, arrivals) do
    if arrivals == [] do
      Enum.each(jobs, &submit_one(dref, &1))
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
        submit_one(dref, job)
      end)
    end
  end

  defp submit_one(dref, job) do
    case Tartarus.request(dref, {:submit, job}, 30_000) do
      {:ok, :ok} -> :ok
      other -> raise "job #{inspect(job.id)} was refused: #{inspect(other)}"
    end
  end

  defp await(opts, robot_hosts, done, total, t0) do
    if map_size(done) >= total do
      done
    else
      receive do
        {:warehouse_job_done, id, at} ->
          done = Map.put(done, id, at)
          retire(opts[:retire], map_size(done), robot_hosts)
          await(opts, robot_hosts, done, total, t0)
      after
        opts[:timeout_ms] -> done
      end
    end
  end

  defp retire(rules, count, robot_hosts) do
    for {i, ^count} <- rules, do: Tartarus.write_plugin(robot_hosts["r#{i}"], :robot, :retire)
    :ok
  end
end
