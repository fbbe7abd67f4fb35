defmodule Tartarus.Host.Server do
  @moduledoc false
  # The server of one host. It adopts arriving agents (phase 1–2 of the hand-off, DESIGN §6:
  # admitted by a process of their own, Tartarus.Host.Arrivals, not here), answers decision
  # queries for migrations that left from here, and watches its agents to
  # restart crashed ones from their arrival snapshot. The host's tables, journal and the
  # watchdog of callback budgets are its warden's (Tartarus.Host.Warden), which outlives it:
  # a server that dies, even by :kill, is restarted and adopts the host's live agents (each
  # recorded under {:proc, pid} in the ledger), so none is orphaned, lost or duplicated.
  #
  # The hand-off protocol (messages, decision rule, guarantees) is specified and decided in
  # Tartarus.Migration.Protocol; this server answers decision queries as the source host,
  # carrying out the protocol's actions.
  #
  # No agent's code runs in this server or blocks it (see Agent.Server's top comment): a
  # create is answered once the agent's init/1 returned (by the agent) or it went down (by
  # this server); a kill is answered when the agent is down; the watchdog of the agents'
  # callback budgets is the host's warden, which stops an overrunning agent and writes
  # {:overran, pid} for this server to read when the agent is down.
  #
  # Nothing any node sends crashes it: unexpected calls are answered
  # {:error, {:bad_message, _}}, unexpected casts and messages are dropped and counted in
  # the ledger ({:count, :dropped}), and a :DOWN counts only for a monitor this server made.
  use GenServer
  require Tartarus.Events

  alias Tartarus.{Clock, Ledger}
  alias Tartarus.Host.{Agents, Arrivals, Parked}

  def start_link({name, opts}) do
    # A replayed prepare (an agent's whole envelope) may queue here: off the heap, a burst
    # neither grows the heap nor makes its collection long (ERTS collects a heap over about
    # 1 MB, queued messages included, on a dirty scheduler).
    GenServer.start_link(__MODULE__, {name, opts},
      name: Tartarus.Host.via(:host, name),
      spawn_opt: [message_queue_data: :off_heap]
    )
  end

  @impl true
  def init({name, opts}) do
    Process.flag(:trap_exit, true)
    # Every arrival is adopted by this one process (one message, after its copy answered
    # `prepared`), and every agent's end is seen here: at normal priority it gets one turn
    # among all runnable agents and its queue grows to hundreds of messages under load. Its work per message is short and bounded, so high
    # priority cannot starve the agents: it drains its queue and waits.
    Process.flag(:priority, :high)

    # The host's tables, journal and watchdog are its warden's (Tartarus.Host.Warden): they
    # outlive this server. A server that starts again beside them runs the same host.
    host = Map.put(Tartarus.Host.Warden.host(name), :pid, self())
    Ledger.clear_stopping(host)
    Ledger.put_server(host, self())

    schedule_sweep(opts[:forward_ttl])

    # Local callers read the host's tables without a call (see Tartarus.Host.local/1).
    {_, _} = Registry.update_value(Tartarus.HostRegistry, {:host, name}, fn _ -> host end)

    state = %{
      host: host,
      monitors: %{},
      # The same agents by pid (to kill them all when this server stops).
      pids: %{},
      # Agents being killed: pid => {escalation timer, callers to answer}.
      killing: %{},
      adopted: 0
    }

    # Timers a server that died took along (they were sent to it): the flush of the host's
    # acknowledgements (its armed flag, the warden's, would stay set and no arrival would
    # arm it again) and the asks about parked copies (the count above zero, no later park
    # would arm them again). Both only tell or ask: doing them now is always safe.
    Arrivals.flush_acks(host)
    {:ok, state |> Agents.adopt_all() |> Parked.event(:ask_parked)}
  end

  @impl true
  def handle_call(_request, from, state) when not Tartarus.Events.is_from(from) do
    Ledger.count(state.host, :dropped)
    {:noreply, state}
  end

  def handle_call(request, from, state) do
    case Tartarus.Wire.check_call(request) do
      :ok -> call(request, from, state)
      error -> {:reply, error, state}
    end
  end

  defp call(:info, _from, state), do: {:reply, state.host, state}

  # A create from another node (a local one does not call this server: Agents.create_local/4).
  # Answered by the agent once its init/1 returned, or on its :DOWN (Agent.Server's top).
  defp call({:create, envelope, args}, from, state) do
    case Agents.start_agent(state, envelope, {:create, args}, 0, from) do
      {:ok, _pid, state} -> {:noreply, state}
      {:error, reason, state} -> {:reply, {:error, reason}, state}
    end
  end

  # Overlay changes come only from this host's own node (Tartarus.connect/3 makes both ends'
  # calls on their own nodes) or, when the host has a trust list, from the nodes it trusts
  # (Tartarus.Security.TrustList.trust_node/2). A link asked for from another node must name
  # a host that exists; the neighbour set holds at most :max_neighbours links.
  defp call({:connect, other, props}, from, state) do
    ns = Ledger.neighbours(state.host)

    with :ok <- overlay_caller(state, from),
         :ok <- link_target(other, from),
         :ok <- neighbour_room(state, ns, other) do
      Ledger.add_link(state.host, other, props)
      {:reply, :ok, state}
    else
      error -> {:reply, error, state}
    end
  end

  defp call({:disconnect, other}, from, state) do
    case overlay_caller(state, from) do
      :ok ->
        Ledger.remove_link(state.host, other)
        {:reply, :ok, state}

      error ->
        {:reply, error, state}
    end
  end

  defp call({:locate, agent}, _from, state) do
    {:reply, Tartarus.Ledger.locate(state.host, agent), state}
  end

  # Answered when the agent is down (killed/2, then the :DOWN): never waits here.
  defp call({:kill, agent}, from, state) do
    case Tartarus.Ledger.locate(state.host, agent) do
      {:here, pid, _id} -> {:noreply, Agents.kill(state, pid, from)}
      other -> {:reply, other, state}
    end
  end

  defp call(:monitored, _from, state), do: {:reply, map_size(state.monitors), state}

  # A paused copy that waited too long parks (Tartarus.Migration.CopyProtocol.step/2): only
  # the copy itself, found as its agent's arriving process here, may hand over its record
  # (Tartarus.Migration.HostProtocol, carried out by Tartarus.Host.Parked).
  defp call({:park, mig, copy, env, src, kind}, from, state),
    do: {:noreply, Parked.event(state, {:park, mig, copy, env, src, kind, from})}

  defp call(:parked, _from, state), do: {:reply, Parked.count(state), state}

  # Restores checkpointed agents and in-doubt copies (persistence); called by
  # Tartarus.start_host/2 after the host's supervisors are up (and by the keeper after a
  # restart: the journal's records are handed out once, see Tartarus.Host.Warden).
  defp call(:restore, _from, state) do
    {reply, state} = Agents.restore(state)
    {:reply, reply, state}
  end

  # How many live agents this server adopted when it started (Agents.adopt_all/1).
  defp call(:adopted, _from, state), do: {:reply, state.adopted, state}

  defp call(:paused, _from, state), do: {:reply, Arrivals.paused(state), state}

  # -- overlay (connect/disconnect) ----------------------------------------------

  defp overlay_caller(state, {caller, _tag}) when is_pid(caller) do
    cond do
      node(caller) == node() -> :ok
      trusted_node?(state.host.opts, node(caller)) -> :ok
      true -> {:error, {:untrusted_node, node(caller)}}
    end
  end

  defp overlay_caller(_state, _from), do: {:error, {:untrusted_node, nil}}

  defp trusted_node?(%{security: %{trust: %Tartarus.Security.TrustList{} = trust}}, node),
    do: Tartarus.Security.TrustList.node_trusted?(trust, node)

  defp trusted_node?(_opts, _node), do: false

  # Tartarus.connect/3 checked both ends before asking; a request from another node is
  # checked here.
  defp link_target(other, {caller, _}) do
    if node(caller) == node() or match?({:ok, _}, Tartarus.Host.Directory.whereis(other)),
      do: :ok,
      else: {:error, {:unknown_host, other}}
  end

  defp neighbour_room(state, ns, other) do
    max = Map.get(state.host.opts, :max_neighbours, 256)

    if other in ns or length(ns) < max,
      do: :ok,
      else: {:error, {:too_many_neighbours, max}}
  end

  @impl true
  # A prepare sent to this server (a replay, or a source of an older build): admitted by a
  # process of its own, as every prepare is (Tartarus.Host.Arrivals).
  def handle_info({:"$tartarus_prepare", _, _, _, _, _, _, _, _} = msg, state) do
    Arrivals.admit_spawn(state.host, msg)
    {:noreply, state}
  end

  # Decision queries and acknowledgements: the host's own part of the protocol
  # (Tartarus.Migration.HostProtocol, carried out by Tartarus.Host.Parked).
  def handle_info({:"$tartarus_decision?", mig, id, copy, a_pid} = msg, state) do
    if Tartarus.Wire.check_decision_query(msg) == :ok do
      {:noreply, Parked.event(state, {:query, mig, id, copy, a_pid})}
    else
      Ledger.count(state.host, :dropped)
      {:noreply, state}
    end
  end

  def handle_info({:"$tartarus_acks", acks} = msg, state) do
    if Tartarus.Wire.check_acks(msg) == :ok do
      {:noreply, Parked.event(state, {:acks, acks})}
    else
      Ledger.count(state.host, :dropped)
      {:noreply, state}
    end
  end

  # A timer that only sends acknowledgements (lazily, batched): it decides nothing. The first
  # arrival after a flush arms it (so an idle host has no timer).
  def handle_info(:"$tartarus_flush_acks", state) do
    Arrivals.flush_acks(state.host)
    {:noreply, state}
  end

  # Asks the sources of parked copies (a timer that only asks: it never decides anything).
  def handle_info(:"$tartarus_ask_parked", state) do
    {:noreply, Parked.event(state, :ask_parked)}
  end

  # A source's answer about a parked copy: revive it (it starts), drop it, or keep it.
  def handle_info({:"$tartarus_decision", mig, copy, d}, state),
    do: {:noreply, Parked.event(state, {:decision, mig, copy, d})}

  # A killed agent still up after its grace: killed for good.
  def handle_info({:timeout, tref, {:"$tartarus_kill", pid}}, state) do
    case state.killing do
      %{^pid => {^tref, _callers}} -> Process.exit(pid, :kill)
      _ -> Ledger.count(state.host, :dropped)
    end

    {:noreply, state}
  end

  # Only a monitor this server made counts: a forged :DOWN changes nothing.
  def handle_info({:DOWN, mref, :process, pid, reason}, state)
      when is_map_key(state.monitors, mref) do
    {entry, monitors} = Map.pop(state.monitors, mref)
    Ledger.drop_proc(state.host, pid)
    # Stopped by the watchdog (Tartarus.Host.Warden): that is its reason.
    overrun = Ledger.take_overrun(state.host, pid)
    state = %{state | monitors: monitors, pids: Map.delete(state.pids, pid)}
    down(state, entry, pid, overrun, reason)
  end

  # An agent a local creator started (Agents.create_local/4): monitored from now on, like the ones
  # this server starts. A forged adoption (of a process of this node) costs one entry per
  # live process at most and changes nothing when that process ends: its :DOWN finds no
  # resident record, hand-off or arriving entry of its pid, and no creator under an
  # unguessable key.
  #
  # The creator recorded the process under {:proc, pid} before it asked: a server that
  # started meanwhile adopted it from there already (Agents.adopt_all/1).
  #
  # A paused copy (Tartarus.Host.Arrivals) is adopted the same way, with `create: false`.
  def handle_info({:"$tartarus_adopt", pid, %{id: id, key: key, owner: owner} = e}, state)
      when is_pid(pid) and node(pid) == node() and is_binary(id) and is_reference(key) do
    cond do
      not is_map_key(state.pids, pid) ->
        entry = %{
          id: id,
          key: key,
          restarts: 0,
          owner: owner,
          create: Map.get(e, :create) != false
        }

        {:noreply, Agents.adopt(state, pid, entry)}

      Ledger.proc?(state.host, pid) ->
        {:noreply, state}

      true ->
        Ledger.count(state.host, :dropped)
        {:noreply, state}
    end
  end

  # An agent that passed through here ended elsewhere (checked by Tartarus.Host.Directory).
  def handle_info({:"$tartarus_gone", id, name}, state) when is_binary(id) do
    Ledger.forget_pointers(state.host, id, name)
    {:noreply, state}
  end

  def handle_info(:sweep, %{host: %{opts: %{forward_ttl: ttl}}} = state) when is_integer(ttl) do
    Ledger.sweep_pointers(state.host, Clock.system_time(:microsecond) - ttl * 1000)
    schedule_sweep(ttl)
    {:noreply, state}
  end

  def handle_info({:EXIT, _pid, _reason}, state), do: {:noreply, state}

  def handle_info(_other, state) do
    Ledger.count(state.host, :dropped)
    {:noreply, state}
  end

  # An agent that moved on (its process ends with {:shutdown, {:migrated, _, _}} after its
  # commit) left nothing to clean: it wrote its pointer over its hand-off record, and left
  # the resident tables, its process record and its snapshot itself (Source.leave/1).
  defp down(state, _entry, pid, :error, {:shutdown, {:migrated, _, _}})
       when not is_map_key(state.killing, pid),
       do: {:noreply, state}

  defp down(state, entry, pid, overrun, reason) do
    reason =
      case overrun do
        {:ok, why} -> why
        :error -> exit_reason(state, pid, reason)
      end

    {kill, killing} = Map.pop(state.killing, pid)
    state = %{state | killing: killing}
    # Its entry in the node's agent table stays while this server decides (a reader finds the
    # agent in transition, not gone: Ledger.take_resident/2): a restarted process replaces it,
    # any other end removes it, a kill's before the killer hears of it.
    resident = Ledger.take_resident(state.host, pid)
    Tartarus.Agent.end_children(state.host, pid)
    # Killed inside a callback, it left its watchdog entry (Tartarus.Agent.Callbacks).
    unless match?({:shutdown, _}, reason), do: Ledger.disarm_watchdog(state.host, pid)
    # Its undecided hand-offs, if it was a source: aborted (it cannot commit them now).
    Ledger.drop_handoffs(state.host, entry.id, pid)
    Ledger.drop_arriving(state.host, entry.id, pid)
    Agents.not_created(state, entry, reason)

    if kill do
      if resident, do: Ledger.unregister_ended(state.host, pid, resident)
      Agents.killed(state, pid, entry, kill)
    end

    {state, restarted?} = Agents.agent_down(state, entry, reason, resident != nil, kill != nil)

    cond do
      # (A kill's entry went above.)
      resident && !restarted? && !kill -> Ledger.unregister_ended(state.host, pid, resident)
      # A restarted process that ended before it registered: its predecessor's entry goes.
      resident == nil and entry.restarts > 0 -> Ledger.unregister_dead(state.host, entry.id)
      true -> :ok
    end

    {:noreply, state}
  end

  # A crash's reason as the agent left it (Agent.Server.terminate/3): the one the :DOWN
  # gives is :noproc when the process ended before this server monitored it.
  defp exit_reason(_state, _pid, reason)
       when reason in [:normal, :shutdown] or
              (is_tuple(reason) and elem(reason, 0) == :shutdown),
       do: reason

  defp exit_reason(state, pid, reason) do
    case Ledger.take_exit_reason(state.host, pid) do
      {:ok, why} -> why
      :error -> reason
    end
  end

  @impl true
  def handle_cast(_other, state) do
    Ledger.count(state.host, :dropped)
    {:noreply, state}
  end

  # Stopping a host (its supervisor stops this server with :shutdown) kills its agents
  # outright: they have no terminate work, and an agent that traps exits must not hold up
  # stop_host (see start_agent/5); its warden then kills any left and closes the journal.
  # A server that crashes leaves them alive: the server started in its place adopts them.
  @impl true
  def terminate(reason, state)
      when reason in [:normal, :shutdown] or
             (is_tuple(reason) and elem(reason, 0) == :shutdown) do
    Ledger.mark_stopping(state.host)
    Tartarus.Host.Warden.kill_all(state.host)
  catch
    _, _ -> :ok
  end

  def terminate(_crash, _state), do: :ok

  defp schedule_sweep(:infinity), do: :ok
  defp schedule_sweep(ttl), do: Clock.send_after(self(), :sweep, max(div(ttl, 2), 10))
end
