defmodule Tartarus.Host.Agents do
  @moduledoc false
  # A host's agents as its server keeps them: starting them (spawned and monitored by the
  # server, or created by a local caller and adopted), killing them, answering creators, and
  # what the server does when one goes down (restart from the arrival snapshot, removal, the
  # pointers of an agent that ended). Runs in the host's server, on the server's state.
  # Restart and shutdown semantics: see docs/architecture.md, "A node's process tree".

  require Logger
  require Tartarus.{Clock, Events}
  alias Tartarus.{Clock, Events, Ledger}
  alias Tartarus.Migration.Protocol

  # How long a killed agent that traps exits may take to stop when its callbacks are not
  # bounded (with a callback budget, that budget).
  @kill_grace 5_000

  # The exit signal stops an agent that does not trap exits at once; one that does stops on
  # it when it next waits for a message (Agent.Server, top), or the watchdog or the
  # escalation timer kills it. The mark tells the agent the signal is real.
  def kill(state, pid, from) do
    case state.killing do
      %{^pid => {tref, callers}} ->
        %{state | killing: %{state.killing | pid => {tref, [from | callers]}}}

      _ ->
        Ledger.mark_kill(state.host, pid)
        Process.exit(pid, :shutdown)

        grace =
          case state.host.opts[:callback_timeout] do
            ms when is_integer(ms) -> ms
            _ -> @kill_grace
          end

        tref = Clock.start_timer(grace, self(), {:"$tartarus_kill", pid})
        %{state | killing: Map.put(state.killing, pid, {tref, [from]})}
    end
  end

  # The killed agent is down (already gone from the ledger, and from the checkpoints now).
  # Killed in the middle of a hand-off: abort it (the destination's paused copy learns so
  # when it asks), unless the move had already committed: then the agent lives on at its
  # destination and the kill follows it there.
  def killed(state, pid, entry, {tref, callers}) do
    Clock.cancel_timer(tref)
    Ledger.clear_kill(state.host, pid)

    reply =
      if Ledger.abort_pending(state.host, entry.id, pid) do
        Tartarus.Host.Persistence.forget(state.host, entry.id)
        {:killed, entry.id}
      else
        Ledger.locate(state.host, entry.id)
      end

    Enum.each(callers, &GenServer.reply(&1, reply))
  end

  # An agent whose init/1 never answered its creator: the host does.
  def not_created(_state, %{create: false}, _reason), do: :ok

  def not_created(state, entry, reason) do
    case Ledger.take_creator(state.host, entry.key) do
      {:ok, from} -> GenServer.reply(from, creation_failed(reason))
      :error -> :ok
    end
  end

  defp creation_failed({:callback_timeout, :init, _} = reason), do: {:error, reason}
  defp creation_failed(reason), do: {:error, {:init_failed, reason}}

  @doc false
  # Creates agent `env` on host `host` (this node's, from Tartarus.Host.local/1) without
  # calling its server: the caller starts the agent's process, records it under
  # {:proc, pid} in the host's ledger and asks the server to adopt it (one message it
  # handles when it can: it monitors the agent from then on, restarts it after a crash,
  # kills it when the host stops; a server that started meanwhile adopted it from the
  # record). The agent answers the caller once its init/1 returned; if it went down first,
  # whoever takes the {:creating, key} entry first (the server, or this caller, which
  # watches the agent, not the server: a server that dies meanwhile changes nothing) answers
  # the failure.
  @spec create_local(map(), Tartarus.Envelope.t(), term(), timeout()) ::
          {:ok, binary()} | {:error, term()}
  def create_local(host, env, args, timeout) do
    if Ledger.stopping?(host) do
      {:error, :host_stopping}
    else
      key = make_ref()
      tag = make_ref()
      Ledger.put_creator(host, key, {self(), tag})
      pid = Tartarus.Agent.Server.spawn_agent(host, key, env, {:create, args})
      mref = Process.monitor(pid)
      entry = %{id: env.id, key: key, restarts: 0, owner: env.owner, create: true}
      Ledger.put_proc(host, pid, entry)
      send(Tartarus.Host.server(host), {:"$tartarus_adopt", pid, entry})
      created(host, key, tag, mref, timeout)
    end
  end

  defp created(host, key, tag, mref, timeout) do
    Clock.receive do
      {^tag, reply} ->
        Process.demonitor(mref, [:flush])
        reply

      {:DOWN, ^mref, :process, _, reason} ->
        # Down before it answered (its answer would have come first): unless the server
        # answers, this caller does.
        case Ledger.take_creator(host, key) do
          {:ok, _} -> creation_failed(reason)
          :error -> receive(do: ({^tag, reply} -> reply))
        end
    after
      timeout ->
        # Unanswered: whoever settles it later finds no entry.
        Process.demonitor(mref, [:flush])

        case Ledger.take_creator(host, key) do
          {:ok, _} -> {:error, {:timeout, host.ref}}
          :error -> receive(do: ({^tag, reply} -> reply))
        end
    end
  end

  # The envelope an agent starts from is its arrival snapshot: kept in the ledger table (not
  # in this server's or the supervisor's heap, which would then hold and garbage-collect
  # every resident's state) for restarts, and read by the agent's process when it starts.
  #
  # This server starts its agents itself, monitored from their first instant (see
  # Tartarus.Agent.Server.start/3): no supervisor call on the path of a hop or a create.
  # Restarts are this server's (agent_down/5); when it stops, its terminate/2 kills them all
  # (as a supervisor with shutdown: :brutal_kill would). If it dies instead (a crash, or an
  # untrappable :kill), its agents live on (their tables are the warden's) and the server
  # started in its place adopts them (adopt_all/1).
  #
  # The envelope goes to the new process as an argument. The host keeps the snapshot a
  # restart starts from under {:snapshot, key} (the agent writes it once resident; for a
  # restart or a restore this server writes it first).
  def start_agent(state, env, mode, restarts \\ 0, creator \\ nil) do
    key = make_ref()

    if match?({:restart, _}, mode) or mode == :restore,
      do: Ledger.put_snapshot(state.host, key, env)

    if creator, do: Ledger.put_creator(state.host, key, creator)

    if Ledger.stopping?(state.host) do
      Ledger.drop_snapshot(state.host, key)
      Ledger.take_creator(state.host, key)
      {:error, :host_stopping, state}
    else
      {pid, mref} = Tartarus.Agent.Server.start(state.host, key, env, mode)
      entry = %{id: env.id, key: key, restarts: restarts, owner: env.owner, create: !!creator}
      Ledger.put_proc(state.host, pid, entry)
      {:ok, pid, watched(state, pid, mref, entry)}
    end
  end

  @doc false
  # Monitors agent process `pid` (described by `entry`) from now on, recorded under
  # {:proc, pid} in the ledger for a server that starts after this one.
  def watch(state, pid, entry) do
    Ledger.put_proc(state.host, pid, entry)
    watched(state, pid, Process.monitor(pid), entry)
  end

  @doc false
  # An agent process that recorded itself under {:proc, pid} (a local create, an admitted
  # copy: Tartarus.Host.Arrivals) and told this server: monitored from now on, the ledger
  # left as it is. (Writing the entry again here would count again a process that already
  # left: this server may take the adoption long after, behind a thousand others.)
  def adopt(state, pid, entry), do: watched(state, pid, Process.monitor(pid), entry)

  defp watched(state, pid, mref, entry) do
    %{
      state
      | monitors: Map.put(state.monitors, mref, entry),
        pids: Map.put(state.pids, pid, mref)
    }
  end

  @doc false
  # A server that starts beside a host's warden (the first, or one started after the last
  # died) monitors every agent process the host recorded: the live ones are its agents from
  # now on, the ones that died meanwhile are seen going down (:noproc) and handled as any
  # other (restarted from their snapshot after a crash). Counts the live ones in :adopted.
  def adopt_all(state) do
    Enum.reduce(Ledger.procs(state.host), state, fn {pid, entry}, state ->
      state = watched(state, pid, Process.monitor(pid), entry)
      if Process.alive?(pid), do: %{state | adopted: state.adopted + 1}, else: state
    end)
  end

  def agent_down(state, entry, reason, resident?, killed?) do
    host = state.host
    # Read the snapshot only to restart from it: copying it here on every departure would
    # fill this process's heap with every passing agent's state.
    snapshot = fn ->
      {:ok, env} = Ledger.fetch_snapshot(host, entry.key)
      env
    end

    {state, restarted?} =
      case after_down(state, entry, reason, resident?, killed?, snapshot) do
        {:restarted, state} -> {state, true}
        state -> {state, false}
      end

    Ledger.drop_snapshot(host, entry.key)
    {state, restarted?}
  end

  defp after_down(state, entry, reason, resident?, killed?, snapshot) do
    host = state.host

    cond do
      killed? ->
        Events.emit(host, %{type: :kill, host: host.ref, agent: entry.id}, kills: 1)
        if resident?, do: ended(host, entry)
        state

      normal_exit?(reason) ->
        state

      Ledger.stopping?(host) ->
        # The host is stopping (see Tartarus.Host.Keeper): its agents are killed with it.
        state

      not resident? ->
        # A paused copy that died before its commit: the source still decides; nothing to do.
        state

      match?({:callback_timeout, _, _}, reason) ->
        # Not restarted: the same callback would hang again.
        ended(host, entry)
        removed(state, entry, reason)

      not Ledger.abort_pending(host, entry.id, nil) ->
        # It crashed after committing a migration: it lives on at the destination.
        state

      entry.restarts < host.opts.max_restarts ->
        n = entry.restarts + 1
        env = snapshot.()

        log_crash(
          host,
          entry,
          env.module,
          reason,
          "restarted from its arrival snapshot (#{n} of #{host.opts.max_restarts})"
        )

        Events.emit(
          host,
          %{type: :crash, host: host.ref, agent: entry.id, reason: reason, restarts: n},
          crashes: 1
        )

        case start_agent(state, env, {:restart, n}, n) do
          {:ok, _pid, state} ->
            {:restarted, state}

          {:error, why, state} ->
            ended(host, entry)
            removed(state, entry, {:restart_failed, why})
        end

      true ->
        module =
          case Ledger.fetch_snapshot(host, entry.key) do
            {:ok, env} -> env.module
            :error -> nil
          end

        log_crash(host, entry, module, reason, "removed: #{entry.restarts} restarts already")

        Events.emit(
          host,
          %{
            type: :crash,
            host: host.ref,
            agent: entry.id,
            reason: reason,
            restarts: entry.restarts
          },
          crashes: 1
        )

        ended(host, entry)
        removed(state, entry, {:too_many_restarts, reason})
    end
  end

  # The one log line of an agent's crash (the host's :crash event is counted, not logged):
  # an operator in iex whose request crashed an agent sees which agent, of which module, on
  # which host, and why. gen_statem's own report of the same crash is dropped by
  # drop_agent_report/2 (Elixir 1.14's Logger happens not to print it; later ones may).
  defp log_crash(host, entry, module, reason, what) do
    Logger.error(
      "agent #{entry.id} (#{inspect(module)}) crashed on host #{inspect(host.ref)}, #{what}: " <>
        describe_crash(reason),
      host: elem(host.ref, 0)
    )
  end

  @doc false
  # A primary logger filter (installed by Tartarus.Application): drops the report
  # gen_statem logs when an agent's process terminates abnormally, since the host logs that
  # crash itself (log_crash/5). A primary filter runs in the process that logs, here the
  # agent's own, so the agent is recognised by its initial call.
  @spec drop_agent_report(:logger.log_event(), term()) :: :logger.filter_return()
  def drop_agent_report(%{msg: {:report, %{label: {:gen_statem, :terminate}}}}, _arg) do
    if Process.get(:"$initial_call") == {Tartarus.Agent.Server, :init, 1},
      do: :stop,
      else: :ignore
  end

  def drop_agent_report(_event, _arg), do: :ignore

  defp describe_crash({kind, reason, stack})
       when kind in [:error, :exit, :throw] and is_list(stack),
       do: Exception.format(kind, reason, stack)

  defp describe_crash(reason), do: inspect(reason, limit: 20, printable_limit: 200)

  # A resident agent killed or removed here: the hosts it visited drop their pointers to it
  # (Tartarus.Ledger.gone/2), as when it stops on its own. Not if it had moved on from here
  # (a pointer here names its newer place): it lives there.
  defp ended(host, entry) do
    unless Ledger.departed?(host, entry.id) do
      with {:ok, env} <- Ledger.fetch_snapshot(host, entry.key), do: Ledger.gone(host, env)
    end

    :ok
  end

  defp removed(state, entry, reason) do
    Events.emit(
      state.host,
      %{type: :removed, host: state.host.ref, agent: entry.id, reason: reason},
      removed: 1
    )

    Tartarus.Host.Persistence.forget(state.host, entry.id)
    if is_pid(entry.owner), do: send(entry.owner, {:tartarus_removed, entry.id, reason})
    state
  end

  defp normal_exit?(:normal), do: true
  defp normal_exit?(:shutdown), do: true
  defp normal_exit?({:shutdown, _}), do: true
  defp normal_exit?(_), do: false

  @doc false
  # Restores checkpointed agents and in-doubt copies (persistence): {reply, state}. Run once
  # by the host's server, called by Tartarus.start_host/2 after the host's supervisors are up.
  # What to start, how and in which order is Tartarus.Migration.HostProtocol.restore/3's.
  def restore(state) do
    {agents, in_doubt} = Tartarus.Host.Warden.take_restore(elem(state.host.ref, 0))
    actions = Tartarus.Migration.HostProtocol.restore(agents, in_doubt, &runnable?/1)
    {state, _pids} = Enum.reduce(actions, {state, []}, &restore/2)
    n = fn tag -> Enum.count(actions, &(is_tuple(&1) and elem(&1, 0) == tag)) end
    {{:ok, n.(:start), n.(:pause)}, state}
  end

  defp restore({:not_started, []}, acc), do: acc

  defp restore({:not_started, envs}, {state, _} = acc) do
    Logger.error(
      "host #{inspect(state.host.ref)}: #{length(envs)} journaled agents not restored, their " <>
        "code is missing (#{inspect(Enum.uniq(Enum.map(envs, & &1.module)), limit: 8)}); " <>
        "their records are kept for a start with it installed"
    )

    acc
  end

  defp restore({:start, env}, {state, pids}) do
    case start_agent(state, env, :restore) do
      {:ok, pid, state} -> {state, [pid | pids]}
      {:error, _reason, state} -> {state, pids}
    end
  end

  # Each restored agent registers itself as it starts: answer once they have (an agent
  # that died first is waited for a bounded time; its :DOWN is handled afterwards).
  defp restore(:await_started, {state, pids}) do
    for pid <- pids do
      Clock.receive do
        {:"$tartarus_restored", ^pid} -> :ok
      after
        5_000 -> :ok
      end
    end

    {state, []}
  end

  # Admission's memory of the copy: in the ledger (Tartarus.Host.Arrivals reads it there).
  defp restore({:pause, mig, copy, env, src, kind}, {state, pids}) do
    with {:ok, pid, state} <- start_agent(state, env, {:paused, mig, copy, src, kind, nil}) do
      Ledger.put_arriving(state.host, env.id, pid)
      store = {Ledger, Ledger.admission_memory(state.host)}
      Protocol.restore_seen(Protocol.destination(store: store), mig, copy, pid)
      {state, pids}
    else
      {:error, _reason, state} -> {state, pids}
    end
  end

  defp runnable?(env),
    do: match?({:ok, _}, Tartarus.CodeCache.manifest(Tartarus.Envelope.modules(env)))
end
