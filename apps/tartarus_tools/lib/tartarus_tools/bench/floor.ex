defmodule TartarusTools.Bench.Floor do
  @moduledoc """
  The floor of a migration: what a hop costs on the BEAM with no platform at all.

  A floor "agent" is a bare process holding the same state as the benchmark's agent (a map
  with a 1 KB binary). One hop from node X to node Y is exactly:

    1. `prepare`: X sends its whole state to a receiver process registered on Y
       (one distribution message);
    2. Y's receiver spawns a *paused* process carrying that state and answers `prepared`
       with its pid (one distribution message and one spawn);
    3. `commit`: X sends `commit` to the paused process and exits (one distribution
       message); the paused process starts and makes the next hop back to X.

  No admission, no journal, no ledger, no supervision, no code check, no forwarding
  pointer: three distribution messages and a spawn, between the same two nodes as the
  platform's benchmark. `run/4` is run on the node that holds the agents' home; it returns
  the wall time in microseconds. Both nodes need `start_receiver/0` first.
  """

  @name :tartarus_bench_floor

  require Tartarus.Clock

  @doc """
  Starts (or finds) this node's floor receiver: the process that turns a `prepare` into a
  paused process. Returns its pid.
  """
  @spec start_receiver() :: pid()
  def start_receiver do
    case Process.whereis(@name) do
      nil ->
        pid = spawn(fn -> receiver() end)

        try do
          Process.register(pid, @name)
          pid
        rescue
          ArgumentError ->
            Process.exit(pid, :kill)
            Process.whereis(@name)
        end

      pid ->
        pid
    end
  end

  @doc "Stops this node's floor receiver, if any."
  @spec stop_receiver() :: :ok
  def stop_receiver do
    case Process.whereis(@name) do
      nil -> :ok
      pid -> Process.exit(pid, :kill) && :ok
    end
  end

  @doc """
  Runs `agents` floor agents, each making `hops` hops between this node and `other`
  (alternately), each carrying `state`. Returns the wall time in microseconds, from the
  first `prepare` to the last agent's end. Raises if an agent does not finish in 5 minutes.
  """
  @spec run(node(), pos_integer(), pos_integer(), term()) :: pos_integer()
  def run(other, agents, hops, state) do
    start_receiver()
    :ok = :erpc.call(other, __MODULE__, :ensure_receiver, [], 10_000)
    owner = self()
    nodes = {node(), other}

    pids =
      for i <- 1..agents do
        spawn(fn ->
          receive do
            :go -> hop({%{state | left: hops}, {owner, i, nodes}})
          end
        end)
      end

    t0 = Tartarus.Clock.machine_time(:microsecond)
    Enum.each(pids, &send(&1, :go))

    for i <- 1..agents do
      Tartarus.Clock.receive do
        {:floor_done, ^i} -> :ok
      after
        300_000 -> raise "floor agent #{i} did not finish its hops within 5 minutes"
      end
    end

    max(Tartarus.Clock.machine_time(:microsecond) - t0, 1)
  end

  @doc false
  def ensure_receiver do
    start_receiver()
    :ok
  end

  defp receiver do
    receive do
      {:prepare, src, agent} ->
        pid = spawn(fn -> paused(agent) end)
        send(src, {:prepared, pid})
        receiver()
    end
  end

  defp paused(agent) do
    receive do
      :commit -> arrive(agent)
    end
  end

  defp arrive({%{left: left} = state, {owner, i, _} = meta}) do
    left = left - 1

    if left <= 0,
      do: send(owner, {:floor_done, i}),
      else: hop({%{state | left: left}, meta})
  end

  defp hop({_state, {_, _, {a, b}}} = agent) do
    dest = if node() == a, do: b, else: a
    send({@name, dest}, {:prepare, self(), agent})

    receive do
      {:prepared, pid} -> send(pid, :commit)
    end
  end
end
