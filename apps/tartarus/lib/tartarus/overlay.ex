defmodule Tartarus.Overlay do
  @moduledoc """
  The node-level process for what hosts send to their neighbours without an agent: signal
  relays (`Tartarus.Signal`) and neighbour broadcasts (`Tartarus.Broadcast`).

  It is registered as `:tartarus_overlay` on every node, so a host addresses a neighbour's
  node as `{:tartarus_overlay, node}` (an atom, not this module's name, so that
  `Tartarus.Signal` and `Tartarus.Broadcast`, which this module calls, do not depend on it
  back: no xref cycle). It owns three ETS tables, read directly by everyone:
  `:tartarus_signals` (the signal fields of this node's hosts),
  `:tartarus_broadcast_subscribers` (broadcast subscriptions) and
  `:tartarus_signal_watchers` (processes watching a signal at a host,
  `Tartarus.Signal.watch/3`). It monitors the hosts it holds fields for, the subscribers
  and the watchers, and forgets them when they go.

  Wire messages (maintainer notes):

      {:"$tartarus_signal", to_host, from_host, name, source, emission, from_hops, age_us}
        (emission packed as {id, strength, span, lifetime, decay, lifetime_decay,
         evaporation, data})
      {:"$tartarus_broadcast", to_host, from_host, message}

  A message for a host that does not run on this node is dropped.
  """
  use GenServer
  require Tartarus.Events

  alias Tartarus.{Broadcast, Host, Signal}

  @doc false
  def start_link(_opts), do: GenServer.start_link(__MODULE__, nil, name: :tartarus_overlay)

  @impl true
  def init(nil) do
    # Ordered by key ({host, name}), so a host's fields are one range: dropping them when
    # the host stops visits that range only (a :set needs a scan of every field of every
    # host: 1,000 hosts stopping with 100 fields each took 8 s of this process, 0.14 s so).
    :ets.new(:tartarus_signals, [:ordered_set, :protected, :named_table, read_concurrency: true])

    :ets.new(:tartarus_broadcast_subscribers, [
      :bag,
      :protected,
      :named_table,
      read_concurrency: true
    ])

    :ets.new(:tartarus_signal_watchers, [:bag, :protected, :named_table, read_concurrency: true])

    {:ok, %{hosts: %{}, subs: %{}}}
  end

  @impl true
  def handle_call(msg, from, state) when not Tartarus.Events.is_from(from) do
    Tartarus.Events.drop(:tartarus_overlay, :call, msg)
    {:noreply, state}
  end

  def handle_call({{:emit, name, e}, host}, _from, state) do
    case local(host) do
      {:ok, info} ->
        Signal.handle_emit(info, name, e)
        {:reply, :ok, watch_host(state, info)}

      error ->
        {:reply, error, state}
    end
  end

  def handle_call(:idle?, _from, state) do
    {:message_queue_len, n} = Process.info(self(), :message_queue_len)
    {:reply, n == 0, state}
  end

  def handle_call({{:subscribe, pid}, host}, _from, state) when is_pid(pid) do
    case local(host) do
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
    case local(host) do
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

  # Anything else (from another node, well-formed or not) is dropped and counted.
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
  def handle_info({:"$tartarus_signal", to, from, name, source, e, hops, age}, state)
      when is_tuple(e) and tuple_size(e) == 8 and is_integer(hops) and is_integer(age) do
    case local(to) do
      {:ok, info} ->
        Signal.handle_relay(info, from, name, source, e, hops, age)
        {:noreply, watch_host(state, info)}

      _ ->
        {:noreply, state}
    end
  end

  def handle_info({:"$tartarus_broadcast", to, from, message} = msg, state) do
    case local(to) do
      {:ok, info} -> Broadcast.deliver(info, from, message, :erlang.external_size(msg))
      _ -> :ok
    end

    {:noreply, state}
  end

  def handle_info({:DOWN, mref, :process, _pid, _reason}, state) do
    case Map.pop(state.subs, mref) do
      {{table, object}, subs} ->
        :ets.delete_object(table, object)
        {:noreply, %{state | subs: subs}}

      {nil, _} ->
        {:noreply, forget_host(state, mref)}
    end
  end

  def handle_info(other, state) do
    Tartarus.Events.drop(:tartarus_overlay, :info, other)
    {:noreply, state}
  end

  # A subscription (a broadcast subscriber, or a signal watcher): `object` {key, pid} in
  # `table`, once, the pid monitored; `subs` maps the monitor to {table, object}. Keys are
  # compared exactly (not as match patterns: a host may be named :_).
  defp add_sub(state, table, {key, pid} = object) do
    if Enum.any?(:ets.lookup(table, key), &(&1 === object)) do
      state
    else
      :ets.insert(table, object)
      %{state | subs: Map.put(state.subs, Process.monitor(pid), {table, object})}
    end
  end

  defp drop_sub(state, table, object) do
    :ets.delete_object(table, object)
    {gone, subs} = Enum.split_with(state.subs, fn {_, sub} -> sub === {table, object} end)
    Enum.each(gone, fn {mref, _} -> Process.demonitor(mref, [:flush]) end)
    %{state | subs: Map.new(subs)}
  end

  defp local(host) do
    if Host.address?(host) and elem(Host.address(host), 1) == node(),
      do: Host.local(host),
      else: {:error, {:unknown_host, host}}
  end

  # Fields of a host are dropped when the host's server stops.
  defp watch_host(state, %{ref: {name, _}, pid: pid}) do
    case state.hosts do
      %{^name => {_mref, ^pid}} ->
        state

      _ ->
        mref = Process.monitor(pid)
        %{state | hosts: Map.put(state.hosts, name, {mref, pid})}
    end
  end

  # The match spec of a host's fields: its range of the ordered_set (the name bound in the
  # key), unless the name reads as match syntax (:_ or :"$1"), then a guard (a full scan).
  defp fields_of(name) do
    if is_atom(name) and (name == :_ or String.starts_with?(Atom.to_string(name), "$")),
      do: [{{{:"$1", :_}, :_}, [{:"=:=", :"$1", {:const, name}}], [true]}],
      else: [{{{name, :_}, :_}, [], [true]}]
  end

  defp forget_host(state, mref) do
    case Enum.find(state.hosts, fn {_, {m, _}} -> m == mref end) do
      {name, _} ->
        :ets.select_delete(:tartarus_signals, fields_of(name))

        # Its watchers stay until they go (their monitors clear them).

        %{state | hosts: Map.delete(state.hosts, name)}

      nil ->
        state
    end
  end
end
