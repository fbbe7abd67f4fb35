defmodule TartarusDashboard.Fleet do
  @moduledoc """
  What the dashboard knows of the other nodes: every node reachable through the overlay,
  read by asking through the neighbours, as the overlay relays an agent search
  (`Tartarus.Locator`): this node asks the nodes of its hosts' overlay neighbours, each of
  them answers with its own snapshot and those of the nodes it asked in turn (each node once,
  at most `:ttl` overlay hops away). No node connects to a node it has no overlay link with,
  so reading a fleet of N nodes costs each node one question from a neighbour, not N
  connections from the dashboard.

  A node's snapshot (`snapshot/1`, taken on that node):
  `%{node, at, path, hosts: [host], agents: [agent], agents_total, health}` where a host is
  `%{name, node, residents, arrivals, departures, refused, bytes, messages, move_failed,
  hop_median_us, hop_p99_us, neighbours: [{name, node}], plugins: [plugin]}`, a plugin
  `%{name, kind, capabilities, last, last_at}` (its last reading, `Tartarus.Plugin`), an agent
  `%{id, name, module, host}`, and `health` that node's latest `TartarusDashboard.Health`
  sample. `path` is the chain of nodes the question went through (the dashboard's node first),
  along which `forward/3` later asks that node for more (its health series).

  A node that did not answer (down, or without this module) appears as
  `%{node, path, error}`.

  The dashboard keeps the last gather in a process of its own (`start_link/1`, `get/1`), read
  by the API without waiting: a request that finds it older than `:fleet_ms` starts the next
  gather in the background.
  """

  use GenServer

  alias Tartarus.Clock

  @max_hosts 500
  @max_agents 1_000
  @call_ms 5_000

  # -- one node's part --------------------------------------------------------------------

  @doc """
  This node's snapshot (see the moduledoc): its hosts (at most #{@max_hosts}, with their
  counters, neighbours and plugins) and agents (at most #{@max_agents}), and its latest health
  sample (starting this node's sampler if it does not run).
  """
  @spec snapshot([node()]) :: map()
  def snapshot(path \\ [node()]) do
    hosts = Tartarus.hosts()
    shown = Enum.take(hosts, @max_hosts)

    agents =
      Enum.flat_map(shown, fn {name, _} = h ->
        case Tartarus.agents(h) do
          list when is_list(list) ->
            Enum.map(list, &%{id: &1.id, name: &1.name, module: &1.module, host: name})

          _ ->
            []
        end
      end)

    %{
      node: node(),
      at: Clock.machine_system_time(:millisecond),
      path: path,
      hosts_total: length(hosts),
      hosts: Enum.flat_map(shown, &host/1),
      agents_total: length(agents),
      agents: Enum.take(agents, @max_agents),
      health: TartarusDashboard.Health.latest()
    }
  end

  defp host({name, node} = h) do
    case Tartarus.status(h) do
      %{counts: _} = st ->
        [
          st
          |> counters()
          |> Map.merge(%{
            name: name,
            node: node,
            neighbours: st.neighbours,
            plugins: Enum.map(st.plugins, &plugin(name, &1))
          })
        ]

      _ ->
        []
    end
  end

  defp plugin(host_name, {pname, desc}) do
    last = Tartarus.Plugin.last_reading(host_name, pname)

    %{
      name: pname,
      kind: Map.get(desc, :kind),
      capabilities: Map.get(desc, :capabilities, []),
      last: last && last.value,
      last_at: last && last.at
    }
  end

  @doc """
  Collects the snapshots of this node and of the nodes reachable from it through the overlay
  (at most `ttl` more hops, skipping `visited`). Returns `{snapshots, visited}`. Called on each
  node by its overlay neighbour.
  """
  @spec collect(non_neg_integer(), [node()], [node()]) :: {[map()], [node()]}
  def collect(ttl, visited, path \\ []) do
    path = path ++ [node()]
    visited = Enum.uniq([node() | visited])
    mine = snapshot(path)
    next = next_nodes(mine) -- visited

    if ttl == 0 do
      {[mine], visited}
    else
      visited = visited ++ next

      Enum.reduce(next, {[mine], visited}, fn n, {acc, vis} ->
        try do
          {snaps, vis} = :erpc.call(n, __MODULE__, :collect, [ttl - 1, vis, path], @call_ms * ttl)
          {acc ++ snaps, Enum.uniq(vis)}
        catch
          kind, reason ->
            {acc ++ [%{node: n, path: path ++ [n], error: describe(kind, reason)}], vis}
        end
      end)
    end
  end

  # The nodes of this node's hosts' neighbours; a node without hosts asks the nodes it is
  # connected to (as the agent search does).
  defp next_nodes(%{hosts: []}), do: Node.list()

  defp next_nodes(%{hosts: hosts}),
    do: Enum.uniq(for h <- hosts, {_, n} <- h.neighbours, n != node(), do: n)

  @doc false
  # Why a node did not answer, in words (an :erpc failure's class and reason).
  def describe_error(kind, reason), do: describe(kind, reason)

  defp describe(:error, {:erpc, :noconnection}), do: "no connection"
  defp describe(:error, {:erpc, :timeout}), do: "no answer in time"
  defp describe(:error, {:exception, :undef, _}), do: "the node has no dashboard code"
  defp describe(kind, reason), do: inspect({kind, reason}, limit: 5, printable_limit: 80)

  @doc """
  Asks the last node of `path` (a snapshot's `path`) along the path, each node asking the next:
  `{:health, points}` answers that node's last `points` health samples, `{:processes, sort,
  limit}` its top processes (`TartarusDashboard.Processes.top/2`). Returns
  `{:ok, answer}` or `{:error, reason}`.
  """
  @spec forward([node()], {:health, pos_integer()} | {:processes, String.t(), pos_integer()}) ::
          {:ok, term()} | {:error, String.t()}
  def forward(path, request) do
    case Enum.drop_while(path, &(&1 == node())) do
      [] ->
        answer(request)

      [next | _] = rest ->
        try do
          :erpc.call(next, __MODULE__, :forward, [rest, request], @call_ms * length(rest))
        catch
          kind, reason -> {:error, describe(kind, reason)}
        end
    end
  end

  defp answer({:health, points}) when is_integer(points) and points > 0,
    do: {:ok, TartarusDashboard.Health.series(points)}

  defp answer({:processes, sort, limit}),
    do: {:ok, TartarusDashboard.Processes.top(sort, limit)}

  defp answer(other), do: {:error, "unknown request #{inspect(other)}"}

  # -- the dashboard's copy ---------------------------------------------------------------

  @doc """
  Starts the dashboard's keeper of the last gather. Options: `:ttl` (overlay hops, default
  8), `:fleet_ms` (how old a gather may be before a request starts the next, default 2,000).
  """
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts), do: GenServer.start_link(__MODULE__, opts)

  @doc """
  The last gather: `%{snapshots: [snapshot], at: ms}` (`at` the dashboard node's clock when it
  ended). A gather older than `:fleet_ms` is renewed in the background; one older than five
  times that, or none yet, is renewed before the answer (waiting at most `timeout`, then
  answering no snapshot).
  """
  @spec get(GenServer.server(), timeout()) :: %{snapshots: [map()], at: integer()}
  def get(fleet, timeout \\ 15_000) do
    GenServer.call(fleet, :get, timeout)
  catch
    # The first gather is slow (a node that does not answer): this node alone meanwhile.
    :exit, {:timeout, _} -> %{snapshots: [], at: Clock.machine_system_time(:millisecond)}
  end

  @doc "Keeps the last gather as it is from now on (a run that ended: its page stays readable)."
  @spec freeze(GenServer.server()) :: :ok
  def freeze(fleet), do: GenServer.call(fleet, :freeze, 60_000)

  @impl true
  def init(opts) do
    {:ok,
     %{
       ttl: Keyword.get(opts, :ttl, 8),
       every: Keyword.get(opts, :fleet_ms, 2_000),
       last: nil,
       task: nil,
       waiting: [],
       frozen: false
     }}
  end

  @impl true
  def handle_call(:get, from, %{last: nil} = s),
    do: {:noreply, start_gather(%{s | waiting: [from | s.waiting]})}

  def handle_call(:get, from, s) do
    age = Clock.machine_system_time(:millisecond) - s.last.at

    cond do
      s.frozen or age <= s.every ->
        {:reply, s.last, s}

      # Nobody asked for a while: what is kept is too old to show, wait for the next one.
      age > 5 * s.every ->
        {:noreply, start_gather(%{s | waiting: [from | s.waiting]})}

      true ->
        {:reply, s.last, start_gather(s)}
    end
  end

  def handle_call(:freeze, _from, s) do
    s = if s.last == nil, do: %{s | last: gather(s.ttl)}, else: s
    {:reply, :ok, %{s | frozen: true}}
  end

  @impl true
  def handle_info({:DOWN, ref, _, _, reason}, %{task: ref} = s) do
    result =
      case reason do
        {:gathered, result} ->
          result

        other ->
          s.last ||
            %{snapshots: [], at: Clock.machine_system_time(:millisecond), error: inspect(other)}
      end

    Enum.each(s.waiting, &GenServer.reply(&1, result))

    {:noreply,
     %{s | task: nil, waiting: [], last: if(s.frozen and s.last, do: s.last, else: result)}}
  end

  def handle_info(_other, s), do: {:noreply, s}

  # One gather at a time, in a process of its own (its result is its exit reason).
  defp start_gather(%{task: nil} = s) do
    ttl = s.ttl
    {_pid, ref} = spawn_monitor(fn -> exit({:gathered, gather(ttl)}) end)
    %{s | task: ref}
  end

  defp start_gather(s), do: s

  defp gather(ttl) do
    {snaps, _} = collect(ttl, [node()])
    %{snapshots: snaps, at: Clock.machine_system_time(:millisecond)}
  end

  @doc false
  # A host's counters from its `Tartarus.status/1`, as the fleet and the API show them.
  def counters(%{counts: c} = st) do
    hops = Map.get(st, :hops) || %{}

    %{
      residents: st.resident,
      arrivals: c.arrivals,
      departures: c.departures,
      refused: c.refused,
      bytes: c.bytes,
      messages: c.messages,
      move_failed: c.move_failed,
      hop_median_us: Map.get(hops, :median_us),
      hop_p99_us: Map.get(hops, :p99_us)
    }
  end
end
