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
  message that it finished. Every grant is two messages through the server (command,
  finished), so its work grows with the number of tasks.

  ## Service time

  `server_ms` (default 0) is the time the server takes to handle one message from a
  robot before it can take the next: a real server reads the request off its socket,
  updates and logs its tables and acknowledges, and the thesis's server (a Prolog process
  over TCP) slowed as the messages grew. It is modelled as the server agent being busy
  (it sleeps, using no CPU, so it does not slow the robots' hosts that share this
  machine's cores); messages that arrive meanwhile queue in its mailbox, one server
  handling them in order. With `k` robots busy on tasks of `T` ms, the server is busy a
  fraction about `k * server_ms / T` of the time; near 1 the queue grows and every
  hand-over waits. At 0 the server is a BEAM process handling a message in microseconds.
  """
  use Tartarus.Agent

  alias TartarusWarehouse.Distributor

  @doc false
  @impl true
  def init(args) do
    {:stay,
     Map.merge(args, %{
       d: Distributor.new(args.world),
       # robot name => state (as the server believes it)
       states: Map.new(args.robots, fn {name, _agent} -> {name, :free} end),
       busy: MapSet.new(),
       pending: [],
       messages: 0
     })
     |> Map.put_new(:server_ms, 0)}
  end

  @doc false
  @impl true
  def handle_message({:submit, spec}, from, s) do
    case Distributor.submit(s.d, spec) do
      {:ok, d, actions} ->
        Tartarus.Agent.reply(from, :ok)
        {:stay, perform(actions, %{s | d: d})}

      {:error, message} ->
        Tartarus.Agent.reply(from, {:error, message})
        {:stay, s}
    end
  end

  def handle_message({:finished, ref, robot, next}, _from, s) do
    if s.server_ms > 0, do: Process.sleep(s.server_ms)

    s = %{
      s
      | states: Map.put(s.states, robot, next),
        busy: MapSet.delete(s.busy, robot),
        messages: s.messages + 1
    }

    {d, actions} = Distributor.done(s.d, ref)
    {:stay, perform(actions, %{s | d: d})}
  end

  def handle_message(:status, from, s) do
    Tartarus.Agent.reply(from, %{messages: s.messages, waiting: Distributor.waiting(s.d)})
    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  defp perform(actions, s) do
    s = Enum.reduce(actions, s, &act/2)
    dispatch(s)
  end

  defp act({:release, ref, a}, s), do: %{s | pending: s.pending ++ [{ref, a}]}
  # A finished ref's resources are free: the server keeps no agent, so a re-issue is a new grant.
  defp act({:reissue, ref, a}, s), do: %{s | pending: s.pending ++ [{ref, a}]}

  defp act({:job_done, id}, s) do
    if s.owner, do: send(s.owner, {:warehouse_job_done, id, System.system_time(:microsecond)})
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
            Tartarus.cast(s.robots[robot], {:execute, ref, a})
            s = %{s | busy: MapSet.put(s.busy, robot), messages: s.messages + 1}

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
  the server when it finished. The programs are on the robot beforehand (they ship with
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

  @doc false
  @impl true
  def init(args) do
    Process.send_after(self(), :subscribe, 0)
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
