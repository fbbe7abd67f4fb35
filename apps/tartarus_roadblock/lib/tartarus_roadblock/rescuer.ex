defmodule TartarusRoadblock.Rescuer do
  @moduledoc """
  The rescue agent the administrator releases (thesis §2.4): a mobile agent carrying the
  rescue program (`TartarusRoadblock.RescueProgram`, shipped as code with the agent) and a
  requirement (the capabilities a robot needs to run it, `[:drive, :claws]`).

  1. **Forage**: a walk of the network along its links, from the administrator's host,
     depth first (an unseen neighbour if there is one, else the nearest unseen host over
     the links seen so far); on each host it reads what the host can do
     (`Tartarus.Agent.capabilities/0`) and which robot, if any, the host talks to (the
     host store's `:robot`), and keeps the candidates.
  2. **Choose**: once every host was seen, the candidates whose capabilities cover the
     requirement, the one with fewest capabilities beyond it first (then by name):
     Claus (claws) over Rudolph (pusher), who lacks `:claws`.
  3. **Go** to the chosen robot's host along the shortest path over the links it saw.
  4. **Install** the program there: from now on each `:tick` request (the scenario's
     clock) runs one control step of the program against that host's devices (`:motors`
     odometry and wheels, `:sonar`, the `:robot`'s claws); it guides the robot to the
     block, off the path with it, and back to its dock. When the program is done the agent
     returns its report to its owner and stops.

  It tells the watcher process (`watcher` in its args) what it does:
  `{:roadblock_visit, host, robot, capabilities}`, `{:roadblock_chosen, robot, host,
  candidates}`, `{:roadblock_installed, robot, host, hops}`.

  Args: `%{requirement: [atom], block: {x, y}, watcher: pid}`.
  """
  use Tartarus.Agent, ships: [TartarusRoadblock.RescueProgram]

  alias TartarusRoadblock.RescueProgram

  @impl true
  @doc "Starts foraging from the host it was released on."
  def init(%{requirement: req, block: {_, _}, watcher: pid} = args)
      when is_list(req) and is_pid(pid) do
    visit(
      Map.merge(args, %{
        phase: :forage,
        visited: [],
        adjacency: %{},
        candidates: [],
        route: [],
        chosen: nil,
        program: nil,
        program_phase: nil
      })
    )
  end

  @impl true
  @doc "Arrived on the next host of its walk."
  def handle_arrival(_ctx, s), do: visit(s)

  @impl true
  @doc "A move failed (a link went down): gives up and returns the reason to its owner."
  def handle_move_failed(_dest, reason, _ctx, s) do
    {:return, {:move_failed, reason}, s}
  end

  @impl true
  @doc "`:tick`: one control step of the installed program (see the moduledoc)."
  def handle_message(:tick, from, %{phase: :running} = s) do
    {:ok, pose} = Tartarus.Agent.read(:motors, :odometry)
    {:ok, us} = Tartarus.Agent.read(:sonar)
    {:ok, holding} = Tartarus.Agent.read(:robot, :holding)

    {commands, program} =
      RescueProgram.control(%{pose: pose, ultrasonic: us, holding: holding}, s.program)

    Enum.each(commands, fn
      {:wheels, l, r} -> :ok = Tartarus.Agent.write(:motors, {:wheels, l, r})
      {:grip, how} -> :ok = Tartarus.Agent.write(:robot, {:grip, how})
    end)

    s = %{s | program: program}
    Tartarus.Agent.reply(from, %{phase: program.phase, pose: pose, holding: holding})

    if program.phase == :done do
      {:return,
       %{
         robot: s.chosen,
         hops: Tartarus.Agent.hops(),
         visited: length(Enum.uniq(s.visited)),
         candidates: s.candidates
       }, s}
    else
      {:stay, s}
    end
  end

  def handle_message(:tick, from, s) do
    Tartarus.Agent.reply(from, %{phase: s.phase})
    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  # -- the walk ---------------------------------------------------------------------

  defp visit(s) do
    host = Tartarus.Agent.host()
    neighbours = Enum.sort(Tartarus.Agent.neighbours())
    robot = Tartarus.Agent.store_get(:robot)
    caps = Tartarus.Agent.capabilities() |> Map.keys() |> Enum.sort()
    first? = host not in s.visited

    s = %{
      s
      | visited: [host | s.visited],
        adjacency: Map.put(s.adjacency, host, neighbours)
    }

    s =
      if first? and robot != nil,
        do: %{s | candidates: s.candidates ++ [%{robot: robot, host: host, capabilities: caps}]},
        else: s

    if first?, do: send(s.watcher, {:roadblock_visit, host, robot, caps})

    case s do
      %{route: [next | rest]} -> {:move, next, %{s | route: rest}}
      %{phase: :forage} -> forage(s, host, neighbours)
      %{phase: :go} -> go(s, host)
    end
  end

  # Depth first: an unseen neighbour if there is one, else the nearest unseen host over
  # the links seen so far; when none is left, choose.
  defp forage(s, host, neighbours) do
    case Enum.find(neighbours, &(&1 not in s.visited)) do
      nil ->
        case nearest_unseen(s.adjacency, host) do
          nil ->
            choose(s, host)

          target ->
            [next | rest] = shortest(s.adjacency, host, target)
            {:move, next, %{s | route: rest}}
        end

      next ->
        {:move, next, s}
    end
  end

  defp nearest_unseen(adj, from) do
    prev = bfs(adj, [from], %{from => nil}, nil)

    adj
    |> Map.keys()
    |> Enum.flat_map(&Map.get(adj, &1))
    |> Enum.uniq()
    |> Enum.reject(&Map.has_key?(adj, &1))
    |> Enum.filter(&Map.has_key?(prev, &1))
    |> Enum.min_by(&{length(path(prev, &1, [])), &1}, fn -> nil end)
  end

  defp choose(s, host) do
    fit =
      s.candidates
      |> Enum.filter(fn c -> Enum.all?(s.requirement, &(&1 in c.capabilities)) end)
      |> Enum.sort_by(&{length(&1.capabilities -- s.requirement), &1.robot})

    case fit do
      [] ->
        {:return, %{robot: nil, hops: Tartarus.Agent.hops(), candidates: s.candidates}, s}

      [best | _] ->
        send(s.watcher, {:roadblock_chosen, best.robot, best.host, s.candidates})
        route = shortest(s.adjacency, host, best.host)
        go(%{s | phase: :go, chosen: best.robot, route: route}, host)
    end
  end

  defp go(%{route: [next | rest]} = s, _host), do: {:move, next, %{s | route: rest}}

  defp go(%{route: []} = s, host) do
    {:ok, dock} = Tartarus.Agent.read(:motors, :odometry)
    program = RescueProgram.init(block: s.block, dock: dock)
    send(s.watcher, {:roadblock_installed, s.chosen, host, Tartarus.Agent.hops()})
    {:stay, %{s | phase: :running, program: program, program_phase: program.phase}}
  end

  # Breadth-first over the links the walk saw; the hosts after `from`, up to `to`.
  defp shortest(_adj, same, same), do: []

  defp shortest(adj, from, to) do
    bfs(adj, [from], %{from => nil}, to) |> path(to, [])
  end

  defp bfs(_adj, [], prev, _to), do: prev

  defp bfs(adj, [h | queue], prev, to) do
    if h == to do
      prev
    else
      new = Enum.reject(Map.get(adj, h, []), &Map.has_key?(prev, &1))
      prev = Enum.reduce(new, prev, &Map.put(&2, &1, h))
      bfs(adj, queue ++ new, prev, to)
    end
  end

  defp path(prev, node, acc) do
    case Map.fetch!(prev, node) do
      nil -> acc
      p -> path(prev, p, [node | acc])
    end
  end
end
