defmodule TartarusWarehouse.Central do
  @moduledoc """
  The centralized baseline of the thesis (§4.7.2): a server on the distributor's host
  commands the robots by messages and grants resources; robots hold every program
  beforehand (`TartarusWarehouse.CentralRobot`, a static agent on each robot host). No
  agent moves.

  The server decides with the same `TartarusWarehouse.Distributor` as the agents' design
  (same queue, same first-come-first-served grants): where an assignment would become a
  task agent that looks for its robot, the server sends it to the robot itself (a free
  robot for a first block, the booked one for the others) and waits for the robot's
  messages that it started and finished. Every task is three messages through the server
  (command, started, finished), so its work grows with the number of tasks running.

  ## Messages and service time

  Every task costs the server three messages, as in the thesis (§4.7.2): the robot's
  `{:started, ref, robot}` when it begins the task, its `{:finished, ref, robot, next}`,
  and the server's command `{:execute, ref, assignment}` to the robot that runs the task
  (for the next task of a job, "the resource is free: execute"). `service_ms` (a number,
  default 0) is the server's time for each of them, and for each job submitted: one FIFO
  server (`TartarusWarehouse.Service`) that handles a message, or sends a command, only
  once its service is done, the one before it done first. It sleeps meanwhile (no CPU).
  With `c` tasks running at once, tasks of `T` ms, the server is busy about
  `3 * c * service_ms / T` of the time; near 1 the queue grows and every hand-over waits.
  At 0 the server is a BEAM process handling a message in microseconds. The Job
  Distributor of the agents' design is charged the same way
  (`TartarusWarehouse.DistributorAgent`).
  """
  use Tartarus.Agent

  alias Tartarus.Clock
  alias TartarusWarehouse.{Distributor, Service}

  @doc false
  @impl true
  def init(args) do
    {:stay,
     Map.merge(args, %{
       d:
         Distributor.new(args.world,
           max_pending_tasks: Map.get(args, :max_pending_tasks, :infinity)
         ),
       # robot name => state (as the server believes it)
       states: Map.new(args.robots, fn {name, _agent} -> {name, :free} end),
       busy: MapSet.new(),
       pending: [],
       messages: 0,
       svc: Service.new(Map.get(args, :service_ms, 0))
     })}
  end

  @doc false
  @impl true
  def handle_message(:status, from, s) do
    Tartarus.Agent.reply(from, %{
      messages: s.messages,
      waiting: Distributor.waiting(s.d),
      service_log: s.svc.log
    })

    {:stay, s}
  end

  # Every other message waits for its service (see "Messages and service time").
  def handle_message(message, from, s), do: {:stay, charge({:in, message, from}, s)}

  @doc false
  @impl true
  def handle_info(:service_due, s) do
    {svc, items, wake} = Service.due(s.svc, Clock.monotonic_time(:microsecond))
    Service.arm(wake)
    {:stay, Enum.reduce(items, %{s | svc: svc}, &serve/2)}
  end

  def handle_info(_msg, s), do: {:stay, s}

  # A message received ({:in, message, from}) or a command to send ({:out, agent, command}).
  # No service time: handled at once, and not logged (nothing to measure).
  defp charge(item, %{svc: %{service_us: 0}} = s), do: serve(item, s)

  defp charge(item, s), do: %{s | svc: Service.charge(s.svc, item)}

  defp serve({:in, message, from}, s) do
    {:stay, s} = handle(message, from, %{s | messages: s.messages + 1})
    s
  end

  defp serve({:out, agent, command}, s) do
    Tartarus.cast(agent, command)
    %{s | messages: s.messages + 1}
  end

  defp handle({:submit, spec}, from, s) do
    case Distributor.submit(s.d, spec) do
      {:ok, d, actions} ->
        Tartarus.Agent.reply(from, :ok)
        {:stay, perform(actions, %{s | d: d})}

      {:error, message} ->
        Tartarus.Agent.reply(from, {:error, message})
        {:stay, s}
    end
  end

  defp handle({:finished, ref, robot, next}, _from, s) do
    s = %{s | states: Map.put(s.states, robot, next), busy: MapSet.delete(s.busy, robot)}
    {d, actions} = Distributor.done(s.d, ref)
    {:stay, perform(actions, %{s | d: d})}
  end

  # The robot began a task: the server notes it (the thesis's robots tell the server as a
  # task is initiated); nothing waits for it.
  defp handle({:started, _ref, _robot}, _from, s), do: {:stay, s}

  defp handle(_other, _from, s), do: {:stay, s}

  defp perform(actions, s) do
    s = Enum.reduce(actions, s, &act/2)
    dispatch(s)
  end

  defp act({:release, ref, a}, s), do: %{s | pending: s.pending ++ [{ref, a}]}
  # A finished ref's resources are free: the server keeps no agent, so a re-issue is a new grant.
  defp act({:reissue, ref, a}, s), do: %{s | pending: s.pending ++ [{ref, a}]}

  defp act({:job_done, id}, s) do
    if s.owner, do: send(s.owner, {:warehouse_job_done, id, Clock.system_time(:microsecond)})
    s
  end

  defp act({:retire, _}, s), do: s

  # Sends every granted assignment whose robot is there.
  defp dispatch(s) do
    {left, s} =
      Enum.reduce(s.pending, {[], s}, fn {ref, a}, {left, s} ->
        case robot_for(a, s) do
          nil ->
            {[{ref, a} | left], s}

          robot ->
            # The command goes out once its service is done (the robot is the server's
            # from now: nothing else is sent to it).
            s = charge({:out, s.robots[robot], {:execute, ref, a}}, s)
            s = %{s | busy: MapSet.put(s.busy, robot)}

            if a.index == 0 do
              {d, actions} = Distributor.started(s.d, ref)
              {left, Enum.reduce(actions, %{s | d: d}, &act/2)}
            else
              {left, s}
            end
        end
      end)

    s = %{s | pending: Enum.reverse(left)}
    # A started first block may have let another one go: dispatch it too.
    if Enum.any?(s.pending, &(robot_for(elem(&1, 1), s) != nil)), do: dispatch(s), else: s
  end

  defp robot_for(a, s) do
    s.states
    |> Enum.sort()
    |> Enum.find_value(fn {robot, state} ->
      if state == a.look_for and not MapSet.member?(s.busy, robot) and
           (a.look_for != :free or reaches?(s.world.robots[robot], a.needs)),
         do: robot
    end)
  end

  defp reaches?(nil, _needs), do: true
  defp reaches?(reach, needs), do: Enum.all?(needs, &MapSet.member?(reach, &1))
end

defmodule TartarusWarehouse.CentralRobot do
  @moduledoc """
  A robot's end of the centralized baseline: a static agent on the robot's host that runs
  what the server commands (`{:execute, ref, assignment}`) on the robot plugin and tells
  the server when it started and when it finished. The programs are on the robot beforehand (they ship with
  this agent when it is created).
  """
  use Tartarus.Agent,
    ships: [
      TartarusWarehouse.Program.Work,
      TartarusWarehouse.Program.Sort,
      TartarusWarehouse.Program.Merge,
      TartarusWarehouse.Program.Add,
      TartarusWarehouse.Program.Sub,
      TartarusWarehouse.Program.Div
    ]

  alias Tartarus.Agent
  alias Tartarus.Clock

  @doc false
  @impl true
  def init(args) do
    Clock.send_after(self(), :subscribe, 0)
    {:stay, Map.put(args, :running, nil)}
  end

  @doc false
  @impl true
  def handle_message({:server, server}, _from, s), do: {:stay, %{s | server: server}}

  def handle_message({:execute, ref, a}, _from, s) do
    :ok = Agent.write(:robot, {:claim, a.look_for, a.needs, Agent.id()})

    :ok =
      Agent.write(
        :robot,
        {:run, Agent.id(), %{job: a.job, seq: a.seq, tasks: a.tasks, next: a.next}}
      )

    Tartarus.cast(s.server, {:started, ref, s.robot})
    {:stay, %{s | running: {ref, a.next}}}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  @doc false
  @impl true
  def handle_info(:subscribe, s) do
    :ok = Agent.subscribe(:robot)
    {:stay, s}
  end

  def handle_info(
        {:plugin_event, :robot, {:finished, _id, _reports}},
        %{running: {ref, next}} = s
      ) do
    Tartarus.cast(s.server, {:finished, ref, s.robot, next})
    {:stay, %{s | running: nil}}
  end

  def handle_info(_msg, s), do: {:stay, s}
end
