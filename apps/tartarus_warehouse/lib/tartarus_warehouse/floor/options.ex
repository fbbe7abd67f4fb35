defmodule TartarusWarehouse.Floor.Options do
  @moduledoc """
  What a floor (`TartarusWarehouse.Floor`) is asked to be, checked before anything
  starts: the options of `TartarusWarehouse.Floor.run/1` and `TartarusWarehouse.Floor.start/1`,
  the robots that start in service, the jobs (planned against the floor's world:
  `TartarusWarehouse.Job.plan/2`) and the events of a batch (`TartarusWarehouse.Job.change/2`).
  Every check answers `{:error, message}` naming the key, what was expected and what
  arrived; nothing here starts a process.
  """

  alias TartarusWarehouse.Job

  @schema [
    robots: [type: :pos_integer, default: 4, doc: "robots"],
    secondary: [type: :non_neg_integer, default: 0, doc: "secondary (relay) nodes"],
    robot_mesh: [
      type: :boolean,
      default: true,
      doc:
        "robots linked to each other (see `TartarusWarehouse.Floor.Build.topology/4`); false: robots meet only through the secondary nodes (Σ) and the distributor's node, so agents cross Σ nodes (the MANET floor of `mix tartarus.warehouse --experiment manet`)"
    ],
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
    scale: [type: {:range, 1.0e-4, 1000}, default: 0.01, doc: "time scale of task durations"],
    paces: [
      type: {:list, {:range, 0.01, 100}},
      default: [],
      doc: "pace of robot i (default 1.0)"
    ],
    jitter: [
      type: {:range, 0, 0.95},
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
        "`{n, event}`: once n jobs completed (0: right after the jobs are submitted), or `{{:ms, t}, event}`: t ms after the submission; `{:retire, i}` (robot i finishes its job and leaves; refused when no robot in service would be left, or none reaching a resource it reaches), `{:join, i}` (a standby robot joins), `{:disconnect, node}`, `{:reconnect, node}` (a robot `\"r<i>\"` or a secondary node `\"s<i>\"` leaves the network, every link of it down, or rejoins it: §4.3's MANET), `{:insert, after_task, task_spec}`, `{:delete, task}` (on-the-fly programming); checked before the floor starts (`TartarusWarehouse.Job.change/2`)"
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
    service_ms: [
      type: {:range, 0, 60_000},
      default: 0,
      doc:
        "the time (ms, a number) that a process serving every robot takes for each message it handles: the central server (`design: :central`: a robot's started and finished, each command it sends, each job submitted) and the Job Distributor (each request or note of a task agent, each job submitted); each is one FIFO server, so messages queue behind it when they come faster than it serves (see `TartarusWarehouse.Service`)"
    ],
    continue: [
      type: :boolean,
      default: false,
      doc:
        "agents continue to the next job's robot without returning to the distributor after each block (the other reading of §4.5.2; see `TartarusWarehouse.Distributor`, \"Agents that continue\")"
    ],
    phi: [
      type: :non_neg_integer,
      default: 0,
      doc: "shared-resource (Φ) nodes in the network (§4.7.1), each on two robots"
    ],
    phi_agents: [
      type: :boolean,
      default: false,
      doc:
        "each Φ node runs a static agent that receives the code of the tasks using its resources from the task agents before their robot runs them (§4.7.1; `TartarusWarehouse.Rack`); the agents' design only (the central server's robots and racks hold their programs a priori, §4.7.2); needs `phi` > 0"
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
    max_pending_tasks: [
      type: :pos_integer,
      default: 10_000,
      doc:
        "the most tasks of jobs accepted and not yet completed that the distributor (or the central server) holds: a job that would take it beyond is answered `{:error, :queue_full}` at once (backpressure: submit it again once a job completed), a job of more tasks than that is refused; `run/1` and `start/1`'s own `jobs` wait in the floor for room instead. The distributor's memory is bounded by it (about 0.5 KB a task, see docs/warehouse.md), well under its heap limit (the host's `:max_heap_size`, 64 MiB by default)"
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

  @start_extra [
    dashboard: [
      type: :any,
      default: nil,
      doc:
        "serve the web dashboard on this port (127.0.0.1), or dashboard options (`port:`, `token:`, ... of `TartarusDashboard`): the floor's hosts and the warehouse panel (`TartarusWarehouse.Panel`); nil: none"
    ]
  ]

  @doc "The options of `TartarusWarehouse.Floor.run/1`."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc "The options of `TartarusWarehouse.Floor.start/1`: those of `run/1`, and `dashboard`."
  @spec start_schema() :: Tartarus.Options.schema()
  def start_schema, do: @schema ++ @start_extra

  @doc """
  Checks `TartarusWarehouse.Floor.run/1`'s options: `{:ok, opts, world, events}` (the
  options with their defaults, the floor's world of resources and robots, and the events
  of the batch, `retire` included, in the order they were given) or `{:error, message}`.

      iex> {:ok, _opts, world, events} = TartarusWarehouse.Floor.Options.check_run(robots: 2, retire: [{2, 1}], jobs: [%{id: 1, tasks: [%{name: "T1", resources: [:rack]}]}])
      iex> {Map.keys(world.robots), events}
      {["r1", "r2"], [{1, {:retire, 2}}]}
      iex> TartarusWarehouse.Floor.Options.check_run(robots: 2, standby: [1, 2])
      {:error, "invalid options given to TartarusWarehouse.Floor.run/1 for key :standby: at least one robot must start in service (a floor with none would take jobs it cannot run), got: [1, 2]"}
  """
  @spec check_run(keyword()) ::
          {:ok, keyword(), Job.world(), [{term(), term()}]} | {:error, String.t()}
  def check_run(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusWarehouse.Floor.run/1"),
         :ok <- check_standby(opts, "run/1"),
         :ok <- check_phi(opts, "run/1"),
         world = world(opts),
         :ok <- plan_all(opts[:jobs], world, opts[:max_pending_tasks]),
         events = events(opts),
         :ok <- check_events(events, world, opts) do
      {:ok, opts, world, events}
    end
  end

  @doc """
  Checks `TartarusWarehouse.Floor.start/1`'s options: `{:ok, opts, world}` or
  `{:error, message}`.

      iex> {:ok, opts, world} = TartarusWarehouse.Floor.Options.check_start(robots: 3, resources: [:rack, :bay])
      iex> {opts[:dashboard], Enum.sort(world.resources)}
      {nil, [:bay, :rack]}
  """
  @spec check_start(keyword()) :: {:ok, keyword(), Job.world()} | {:error, String.t()}
  def check_start(opts) do
    with {:ok, opts} <-
           Tartarus.Options.validate(opts, start_schema(), "TartarusWarehouse.Floor.start/1"),
         :ok <- check_standby(opts, "start/1"),
         :ok <- check_phi(opts, "start/1"),
         world = world(opts),
         :ok <- plan_all(opts[:jobs], world, opts[:max_pending_tasks]) do
      {:ok, opts, world}
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

  # Racks need Φ nodes to run on.
  defp check_phi(opts, fun) do
    if opts[:phi_agents] and opts[:phi] == 0,
      do:
        {:error,
         "invalid options given to TartarusWarehouse.Floor.#{fun} for key :phi_agents: the racks run on the Φ nodes, and the floor has none (give phi: n > 0)"},
      else: :ok
  end

  # `run/1`'s events (and `retire`), checked before anything starts: when each fires, and
  # what it is (`TartarusWarehouse.Job.change/2`), with robots of this floor.
  defp check_events(events, world, opts) do
    Enum.find_value(events, :ok, fn
      {:retire_option, other} ->
        {:error,
         "invalid options given to TartarusWarehouse.Floor.run/1 for key :retire: expected {robot_index, n}, got: #{inspect(other, limit: 5)}"}

      {n, event} when (is_integer(n) and n >= 0) or (is_tuple(n) and tuple_size(n) == 2) ->
        with :ok <- check_when(n),
             {:ok, event} <- Job.change(event, world),
             :ok <- check_node(event, opts) do
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

  defp check_node({what, i}, opts) when what in [:retire, :join] do
    if i > opts[:robots],
      do: {:error, "no robot #{inspect(i)} (the floor has robots 1..#{opts[:robots]})"},
      else: :ok
  end

  defp check_node({what, node}, opts) when what in [:disconnect, :reconnect] do
    if node in leaving_nodes(opts[:robots], opts[:secondary]),
      do: :ok,
      else:
        {:error,
         "change {#{inspect(what)}, _}: no robot or secondary node #{inspect(node)} (the floor has r1..r#{opts[:robots]}#{if opts[:secondary] > 0, do: " and s1..s#{opts[:secondary]}", else: ""})"}
  end

  defp check_node(_event, _opts), do: :ok

  @doc """
  The nodes of a floor of `robots` robots and `secondary` Σ nodes that may leave the
  network and rejoin it (`{:disconnect, node}`, `{:reconnect, node}`): the robots and
  the Σ nodes (the distributor's node leaves only by `{:kill_distributor, ms}`).

      iex> TartarusWarehouse.Floor.Options.leaving_nodes(2, 1)
      ["r1", "r2", "s1"]
  """
  @spec leaving_nodes(pos_integer(), non_neg_integer()) :: [String.t()]
  def leaving_nodes(robots, secondary),
    do: Enum.map(1..robots, &"r#{&1}") ++ Enum.map(1..secondary//1, &"s#{&1}")

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

  # Every job planned, and none larger than the distributor's bound (it would never fit:
  # the floor's backlog would wait for it for ever).
  defp plan_all(jobs, world, max_tasks) do
    Enum.find_value(jobs, :ok, fn spec ->
      with {:ok, plan} <- Job.plan(spec, world),
           tasks =
             for(seq <- plan.sequences, b <- seq, reduce: 0, do: (n -> n + length(b.tasks))),
           true <- tasks <= max_tasks do
        nil
      else
        {:error, m} ->
          {:error, m}

        false ->
          {:error,
           "invalid options given to TartarusWarehouse.Floor for key :jobs: job #{inspect(spec.id)} has more tasks than max_pending_tasks (#{max_tasks}): the distributor would never take it"}
      end
    end)
  end

  # `retire` as events, then `events`, in the order given.
  defp events(opts) do
    retire =
      Enum.map(opts[:retire], fn
        {i, n} -> {n, {:retire, i}}
        other -> {:retire_option, other}
      end)

    retire ++ opts[:events]
  end
end
