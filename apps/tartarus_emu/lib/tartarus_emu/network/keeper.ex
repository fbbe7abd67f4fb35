defmodule TartarusEmu.Network.Keeper do
  @moduledoc false
  # The one process of a TartarusEmu.Network. It owns the network's bookkeeping table (broken
  # links, isolated and killed nodes: plain keys `{key}` in a public ETS table, read by the
  # caller without a call) and knows what to clean up: the virtual hosts and the owners of the
  # peer nodes. It monitors the process that started the network and cleans up if it dies.
  #
  # Peer nodes: `:peer` links a peer to the process that starts it, and the peer stops when
  # that process exits (even normally). So each peer gets an owner process that starts it,
  # starts its hosts, and lives until told to stop or until this keeper dies; several owners
  # start their peers at once (bounded concurrency) while the caller waits.
  use GenServer

  alias Tartarus.MachineClock
  require Tartarus.MachineClock

  @spec start(pid()) :: {:ok, pid(), :ets.tid()}
  def start(owner) do
    {:ok, pid} = GenServer.start(__MODULE__, owner)
    {:ok, pid, GenServer.call(pid, :table)}
  end

  def stop(keeper) do
    GenServer.call(keeper, :stop, :infinity)
  catch
    :exit, _ -> :ok
  end

  def track_hosts(keeper, names), do: GenServer.call(keeper, {:track_hosts, names})

  # -- table -----------------------------------------------------------------------

  def put(%{table: t}, key), do: :ets.insert(t, {key})
  def delete(%{table: t}, key), do: :ets.delete(t, key)
  def member?(%{table: t}, key), do: :ets.member(t, key)
  def keys(%{table: t}, tag), do: :ets.select(t, [{{{tag, :"$1"}}, [], [:"$1"]}])

  # -- peers -----------------------------------------------------------------------

  # Starts one peer per spec (%{name, args, hosts: [{topo, host_name}], host_opts}).
  # Returns {:ok, [{owner, node}]} in spec order, or an error after stopping what started.
  def start_peers(keeper, specs, concurrency) do
    results =
      specs
      |> Task.async_stream(fn spec -> start_owner(keeper, spec) end,
        max_concurrency: concurrency,
        timeout: :infinity
      )
      |> Enum.map(fn {:ok, r} -> r end)

    case Enum.find(results, &match?({:error, _}, &1)) do
      nil ->
        {:ok, Enum.map(results, fn {:ok, owner, node} -> {owner, node} end)}

      error ->
        for {:ok, owner, _} <- results, do: stop_owner(owner)
        error
    end
  end

  defp start_owner(keeper, spec) do
    owner = spawn(fn -> owner_init(keeper) end)
    GenServer.call(keeper, {:owner, owner})
    ref = Process.monitor(owner)
    send(owner, {:start, self(), ref, spec})

    receive do
      {^ref, {:ok, node}} ->
        Process.demonitor(ref, [:flush])
        GenServer.call(keeper, {:owner_node, owner, node})
        {:ok, owner, node}

      {^ref, error} ->
        Process.demonitor(ref, [:flush])
        stop_owner(owner)
        {:error, {:peer_failed, spec.name, error}}

      {:DOWN, ^ref, _, _, reason} ->
        {:error, {:peer_failed, spec.name, reason}}
    end
  end

  def kill_peer(keeper, node), do: GenServer.call(keeper, {:to_owner, node, :kill}, 120_000)
  def restart_peer(keeper, node), do: GenServer.call(keeper, {:to_owner, node, :restart}, 120_000)

  defp stop_owner(owner) do
    ref = Process.monitor(owner)
    send(owner, {:stop, self(), ref})

    MachineClock.receive do
      {:DOWN, ^ref, _, _, _} -> :ok
    after
      60_000 ->
        Process.exit(owner, :kill)
        :ok
    end
  end

  # The owner of one peer node.
  defp owner_init(keeper) do
    kref = Process.monitor(keeper)

    receive do
      {:start, from, ref, spec} ->
        case boot(spec) do
          {:ok, peer, node} ->
            send(from, {ref, {:ok, node}})
            owner_loop(%{keeper: kref, peer: peer, node: node, spec: spec})

          error ->
            send(from, {ref, error})
        end

      {:stop, _from, _ref} ->
        :ok

      {:DOWN, ^kref, _, _, _} ->
        :ok
    end
  end

  defp boot(spec) do
    case TartarusTools.Peer.start(spec.name, args: spec.args) do
      {:ok, peer, node} ->
        case :erpc.call(
               node,
               __MODULE__,
               :start_local_hosts,
               [spec.hosts, spec.host_opts, Map.get(spec, :node_opts, %{})],
               60_000
             ) do
          :ok ->
            {:ok, peer, node}

          error ->
            TartarusTools.Peer.stop(peer)
            error
        end

      error ->
        error
    end
  end

  defp owner_loop(s) do
    kref = s.keeper

    receive do
      {:stop, _from, _ref} ->
        if s.peer, do: TartarusTools.Peer.stop(s.peer)
        :ok

      {:DOWN, ^kref, _, _, _} ->
        if s.peer, do: TartarusTools.Peer.stop(s.peer)
        :ok

      {:kill, from, ref} ->
        if s.peer, do: TartarusTools.Peer.stop(s.peer)
        send(from, {ref, :ok})
        owner_loop(%{s | peer: nil})

      {:restart, from, ref} ->
        if s.peer, do: TartarusTools.Peer.stop(s.peer)

        case boot(s.spec) do
          {:ok, peer, _node} ->
            send(from, {ref, :ok})
            owner_loop(%{s | peer: peer})

          error ->
            send(from, {ref, error})
            owner_loop(%{s | peer: nil})
        end
    end
  end

  @doc false
  # Runs on a peer: starts its hosts.
  def start_local_hosts(hosts, opts, node_opts \\ %{}) do
    Enum.reduce_while(hosts, :ok, fn {topo, name}, :ok ->
      case Tartarus.start_host(name, Keyword.merge(opts, Map.get(node_opts, topo, []))) do
        {:ok, _} -> {:cont, :ok}
        error -> {:halt, error}
      end
    end)
  end

  # -- server ----------------------------------------------------------------------

  @impl true
  def init(owner) do
    Process.flag(:trap_exit, true)
    ref = Process.monitor(owner)
    table = :ets.new(:tartarus_emu_network, [:set, :public, read_concurrency: true])
    {:ok, %{owner: ref, table: table, hosts: [], owners: %{}, nodes: %{}}}
  end

  @impl true
  def handle_call(:table, _from, s), do: {:reply, s.table, s}
  def handle_call({:track_hosts, names}, _from, s), do: {:reply, :ok, %{s | hosts: names}}

  def handle_call({:owner, pid}, _from, s) do
    {:reply, :ok, %{s | owners: Map.put(s.owners, pid, Process.monitor(pid))}}
  end

  def handle_call({:owner_node, pid, node}, _from, s),
    do: {:reply, :ok, %{s | nodes: Map.put(s.nodes, pid, node)}}

  def handle_call({:to_owner, node, op}, from, s) do
    case owner_of(s, node) do
      nil ->
        {:reply, {:error, {:unknown_node, node}}, s}

      owner ->
        # Answered by a helper so the keeper stays responsive while a peer restarts.
        spawn(fn ->
          ref = Process.monitor(owner)
          send(owner, {op, self(), ref})

          reply =
            receive do
              {^ref, r} -> r
              {:DOWN, ^ref, _, _, reason} -> {:error, {:owner_down, reason}}
            end

          GenServer.reply(from, reply)
        end)

        {:noreply, s}
    end
  end

  def handle_call(:stop, _from, s) do
    cleanup(s)
    {:stop, :normal, :ok, s}
  end

  @impl true
  def handle_info({:DOWN, ref, _, _, _}, %{owner: ref} = s) do
    cleanup(s)
    {:stop, :normal, s}
  end

  def handle_info({:DOWN, _ref, _, pid, _}, s) do
    {:noreply, %{s | owners: Map.delete(s.owners, pid), nodes: Map.delete(s.nodes, pid)}}
  end

  def handle_info(_msg, s), do: {:noreply, s}

  defp owner_of(s, node) do
    Enum.find_value(s.nodes, fn {pid, n} -> if n == node, do: pid end)
  end

  defp cleanup(s) do
    s.owners
    |> Map.keys()
    |> Task.async_stream(&stop_owner/1, max_concurrency: 8, timeout: :infinity)
    |> Stream.run()

    Enum.each(s.hosts, &Tartarus.stop_host/1)
  end
end
