defmodule Tartarus.Overlay do
  @moduledoc """
  What hosts send to their neighbours without an agent: signal relays (`Tartarus.Signal`)
  and neighbour broadcasts (`Tartarus.Broadcast`). Each host has its own overlay process
  (`Tartarus.Overlay.Host`, in the host's tree), as a host on its own device would: a host
  flooded with relays queues them in its own mailbox, and no other host's signal waits
  behind them.

  This module is the node's door for the overlay (registered as `:tartarus_overlay`, an
  atom rather than this module's name, so that `Tartarus.Signal` and `Tartarus.Broadcast`
  do not depend on it back: no xref cycle): what another node sends to a host of this node
  arrives here and is passed on to the host's overlay process, as a device's network
  interface passes it to the one host it runs. Hosts of one node send to each other's
  overlay processes directly. It owns the three ETS tables the hosts' overlay processes
  write and everyone reads: `:tartarus_signals` (the signal fields of this node's hosts),
  `:tartarus_broadcast_subscribers` and `:tartarus_signal_watchers`
  (`Tartarus.Signal.watch/3`), and a table of the relays in flight over links with a latency
  (`Tartarus.Signal.settle/1` waits for them). It monitors the hosts' overlay processes and
  drops what a host's process left in the tables when it goes.

  Wire messages (maintainer notes), to `{:tartarus_overlay, node}` from another node or to a
  host's overlay process:

      {:"$tartarus_signal", to_host, from_host, name, source, emission, from_hops, age_us}
        (emission packed as {id, strength, span, lifetime, decay, lifetime_decay,
         evaporation, data})
      {:"$tartarus_broadcast", to_host, from_host, message}

  A message for a host that does not run on this node is dropped. Calls `{request, host}`
  from another node (emit, subscribe, watch, ...) are passed on to the host's overlay
  process, which answers the caller itself.
  """
  use GenServer
  require Tartarus.Events

  alias Tartarus.Host

  @doc false
  def start_link(_opts), do: GenServer.start_link(__MODULE__, nil, name: :tartarus_overlay)

  @impl true
  def init(nil) do
    # Ordered by key ({host, name}), so a host's fields are one range: dropping them when
    # the host stops visits that range only (a :set needs a scan of every field of every
    # host: 1,000 hosts stopping with 100 fields each took 8 s of this process, 0.14 s so).
    # Public: each host's overlay process writes its own host's rows.
    :ets.new(:tartarus_signals, [
      :ordered_set,
      :public,
      :named_table,
      read_concurrency: true,
      write_concurrency: true
    ])

    :ets.new(:tartarus_broadcast_subscribers, [
      :bag,
      :public,
      :named_table,
      read_concurrency: true,
      write_concurrency: true
    ])

    :ets.new(:tartarus_signal_watchers, [
      :bag,
      :public,
      :named_table,
      read_concurrency: true,
      write_concurrency: true
    ])

    :ets.new(:tartarus_overlay_in_flight, [:set, :public, :named_table, write_concurrency: true])

    {:ok, %{hosts: %{}, subs: %{}}}
  end

  @impl true
  def handle_call(msg, from, state) when not Tartarus.Events.is_from(from) do
    Tartarus.Events.drop(:tartarus_overlay, :call, msg)
    {:noreply, state}
  end

  # A call from another node for one of this node's hosts: its overlay process answers.
  def handle_call({_request, host} = msg, from, state) do
    with true <- Host.address?(host),
         {name, node} when node == node() <- Host.address(host),
         pid when is_pid(pid) <- Host.overlay_pid(name) do
      send(pid, {:"$gen_call", from, msg})
    else
      _ ->
        Tartarus.Events.drop(:tartarus_overlay, :call, msg)
        Tartarus.Events.reply(from, {:error, {:unknown_host, host}})
    end

    {:noreply, state}
  end

  # Anything else (from another node, well-formed or not) is dropped and counted.
  def handle_call(msg, from, state) do
    Tartarus.Events.drop(:tartarus_overlay, :call, msg)
    Tartarus.Events.reply(from, {:error, :unexpected_call})
    {:noreply, state}
  end

  # A host's overlay process says it started: watched, so what it leaves is dropped.
  @impl true
  def handle_cast({:"$tartarus_host_overlay", name, pid}, state) when is_pid(pid) do
    if node(pid) == node() and Host.overlay_pid(name) == pid do
      case state.hosts do
        %{^name => {mref, _}} -> Process.demonitor(mref, [:flush])
        _ -> :ok
      end

      {:noreply, %{state | hosts: Map.put(state.hosts, name, {Process.monitor(pid), pid})}}
    else
      {:noreply, state}
    end
  end

  # A host's overlay process took a subscription (a broadcast subscriber or a signal
  # watcher): watched here, so it outlives the host's process (as the host's restart does)
  # and goes when the subscriber goes.
  def handle_cast({:"$tartarus_sub", table, {_key, pid} = object}, state)
      when table in [:tartarus_broadcast_subscribers, :tartarus_signal_watchers] and is_pid(pid) do
    {:noreply, %{state | subs: Map.put(state.subs, Process.monitor(pid), {table, object})}}
  end

  def handle_cast({:"$tartarus_unsub", table, object}, state) do
    {gone, subs} = Enum.split_with(state.subs, fn {_, sub} -> sub === {table, object} end)
    Enum.each(gone, fn {mref, _} -> Process.demonitor(mref, [:flush]) end)
    {:noreply, %{state | subs: Map.new(subs)}}
  end

  def handle_cast(msg, state) do
    Tartarus.Events.drop(:tartarus_overlay, :cast, msg)
    {:noreply, state}
  end

  @impl true
  def handle_info({:"$tartarus_signal", to, _, _, _, _, _, _} = msg, state),
    do: {:noreply, pass_on(state, to, msg)}

  def handle_info({:"$tartarus_broadcast", to, _, _} = msg, state),
    do: {:noreply, pass_on(state, to, msg)}

  def handle_info({:DOWN, mref, :process, pid, _reason}, state) do
    case Map.pop(state.subs, mref) do
      {{table, object}, subs} ->
        :ets.delete_object(table, object)
        {:noreply, %{state | subs: subs}}

      {nil, _} ->
        case Enum.find(state.hosts, fn {_, entry} -> entry == {mref, pid} end) do
          {name, _} ->
            Tartarus.Overlay.Host.forget(name, pid)
            {:noreply, %{state | hosts: Map.delete(state.hosts, name)}}

          nil ->
            {:noreply, state}
        end
    end
  end

  def handle_info(other, state) do
    Tartarus.Events.drop(:tartarus_overlay, :info, other)
    {:noreply, state}
  end

  defp pass_on(state, to, msg) do
    with true <- Host.address?(to),
         {name, node} when node == node() <- Host.address(to),
         pid when is_pid(pid) <- Host.overlay_pid(name) do
      send(pid, msg)
    end

    state
  end
end

defmodule Tartarus.Overlay.Host do
  @moduledoc false
  # One host's overlay process (a child of the host's supervisor, registered as
  # {:overlay, name} in Tartarus.HostRegistry): it takes the host's signal emissions and
  # relays, its broadcasts, and its subscriptions and watches, and writes the host's rows of
  # the node's overlay tables (see Tartarus.Overlay). When it stops, the host's fields go
  # with it; subscribers and watchers stay until they go (the node's overlay watches them).
  use GenServer
  require Tartarus.Events

  alias Tartarus.{Broadcast, Host, Signal}

  def start_link(name),
    do: GenServer.start_link(__MODULE__, name, name: Host.via(:overlay, name))

  @impl true
  def init(name) do
    Process.flag(:trap_exit, true)
    # What an earlier incarnation of this host left (it was killed).
    forget(name, nil)
    GenServer.cast(:tartarus_overlay, {:"$tartarus_host_overlay", name, self()})
    {:ok, %{name: name}}
  end

  @impl true
  def terminate(_reason, %{name: name}), do: forget(name, self())

  @doc false
  # Drops host `name`'s fields and its count of relays in flight, unless a newer overlay
  # process than `pid` runs for it.
  def forget(name, pid) do
    if pid == nil or Host.overlay_pid(name) in [nil, pid] do
      :ets.select_delete(:tartarus_signals, fields_of(name))
      :ets.delete(:tartarus_overlay_in_flight, name)
    end

    :ok
  rescue
    ArgumentError -> :ok
  end

  @impl true
  def handle_call(msg, from, state) when not Tartarus.Events.is_from(from) do
    Tartarus.Events.drop(:tartarus_overlay, :call, msg)
    {:noreply, state}
  end

  def handle_call({{:emit, name, e}, host}, _from, state) do
    case local(host, state) do
      {:ok, info} ->
        Signal.handle_emit(info, name, e)
        {:reply, :ok, state}

      error ->
        {:reply, error, state}
    end
  end

  def handle_call({{:subscribe, pid}, host}, _from, state) when is_pid(pid) do
    case local(host, state) do
      {:ok, %{ref: {name, _}}} ->
        {:reply, :ok, add_sub(state, :tartarus_broadcast_subscribers, {name, pid})}

      error ->
        {:reply, error, state}
    end
  end

  def handle_call({{:unsubscribe, pid}, host}, _from, state) when is_pid(pid) do
    {name, _} = Host.address(host)
    {:reply, :ok, drop_sub(state, :tartarus_broadcast_subscribers, {name, pid})}
  end

  def handle_call({{:watch, name, pid}, host}, _from, state) when is_pid(pid) do
    case local(host, state) do
      {:ok, %{ref: {host_name, _}}} ->
        {:reply, :ok, add_sub(state, :tartarus_signal_watchers, {{host_name, name}, pid})}

      error ->
        {:reply, error, state}
    end
  end

  def handle_call({{:unwatch, name, pid}, host}, _from, state) when is_pid(pid) do
    {host_name, _} = Host.address(host)
    {:reply, :ok, drop_sub(state, :tartarus_signal_watchers, {{host_name, name}, pid})}
  end

  def handle_call(msg, from, state) do
    Tartarus.Events.drop(:tartarus_overlay, :call, msg)
    Tartarus.Events.reply(from, {:error, :unexpected_call})
    {:noreply, state}
  end

  @impl true
  def handle_cast(msg, state) do
    Tartarus.Events.drop(:tartarus_overlay, :cast, msg)
    {:noreply, state}
  end

  @impl true
  def handle_info({:"$tartarus_delayed", msg}, state) do
    Host.overlay_in_flight(state.name, -1)
    handle_info(msg, state)
  end

  def handle_info({:"$tartarus_signal", to, from, name, source, e, hops, age}, state)
      when is_tuple(e) and tuple_size(e) == 8 and is_integer(hops) and is_integer(age) do
    with {:ok, info} <- local(to, state),
         do: Signal.handle_relay(info, from, name, source, e, hops, age)

    {:noreply, state}
  end

  def handle_info({:"$tartarus_broadcast", to, from, message} = msg, state) do
    with {:ok, info} <- local(to, state),
         do: Broadcast.deliver(info, from, message, :erlang.external_size(msg))

    {:noreply, state}
  end

  def handle_info({:EXIT, _pid, reason}, state), do: {:stop, reason, state}

  def handle_info(other, state) do
    Tartarus.Events.drop(:tartarus_overlay, :info, other)
    {:noreply, state}
  end

  # A subscription (a broadcast subscriber, or a signal watcher): `object` {key, pid} in
  # `table`, once; the node's overlay monitors the pid. Keys are compared exactly (not as
  # match patterns: a host may be named :_).
  defp add_sub(state, table, {key, _pid} = object) do
    unless Enum.any?(:ets.lookup(table, key), &(&1 === object)) do
      :ets.insert(table, object)
      GenServer.cast(:tartarus_overlay, {:"$tartarus_sub", table, object})
    end

    state
  end

  defp drop_sub(state, table, object) do
    :ets.delete_object(table, object)
    GenServer.cast(:tartarus_overlay, {:"$tartarus_unsub", table, object})
    state
  end

  # Only this process's own host.
  defp local(host, %{name: name}) do
    if Host.address?(host) and Host.address(host) == {name, node()},
      do: Host.local(host),
      else: {:error, {:unknown_host, host}}
  end

  # The match spec of a host's fields: its range of the ordered_set (the name bound in the
  # key), unless the name reads as match syntax (:_ or :"$1"), then a guard (a full scan).
  defp fields_of(name) do
    if is_atom(name) and (name == :_ or String.starts_with?(Atom.to_string(name), "$")),
      do: [{{{:"$1", :_}, :_}, [{:"=:=", :"$1", {:const, name}}], [true]}],
      else: [{{{name, :_}, :_}, [], [true]}]
  end
end
