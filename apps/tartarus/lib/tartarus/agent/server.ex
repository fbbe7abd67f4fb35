defmodule Tartarus.Agent.Server do
  @moduledoc false
  # The process of one agent. It runs the agent's callbacks (Tartarus.Agent.Callbacks) and
  # carries out their actions; for a move or a clone it runs the source side of the hand-off
  # itself (Tartarus.Migration.Source: hand-offs of many agents proceed in parallel; the host
  # server is involved only at the destination, to admit and create the paused copy); while
  # it is a paused copy at a destination, Tartarus.Migration.Arrival runs it. The hand-off's
  # decisions are Tartarus.Migration.Protocol's (its moduledoc is the specification).
  #
  # Callbacks never block the host. The agent's code (init/1 included) runs only in this
  # process, after it started (the host spawns it and returns at once, see start/4).
  # A create is answered by whoever settles it first, through an ETS entry
  # {{:creating, key}, from} the host writes before it starts the process (:ets.take makes
  # the answer exactly-once): this process once init/1 returned and the agent is resident
  # ({:ok, id}) or failed ({:error, {:init_failed, _}}), else the host when the process
  # goes down ({:error, {:callback_timeout, :init, ms}} or {:error, {:init_failed, reason}}).
  #
  # Each callback has a budget, the host option :callback_timeout (ms): see
  # Tartarus.Agent.Callbacks (the watchdog).
  #
  # A kill never blocks the host server either: it marks {:kill, pid} in its ledger, sends
  # exit signal :shutdown, and answers the caller when the process is down. An agent that
  # traps exits gets the signal as {:EXIT, host_pid, :shutdown}: this process stops on it
  # (whatever the agent's code would say) when the mark is there, and ignores a forged one;
  # an agent stuck in a callback is stopped by the watchdog, and the host kills it anyway
  # after the callback budget (5 s with :infinity).
  #
  # Stopping a host kills its agents outright (its server's terminate/2): this process has no
  # terminate work but ending its children, and an agent that traps exits must not hold up
  # stop_host.
  use GenServer, restart: :temporary, shutdown: :brutal_kill
  require Tartarus.Events

  alias Tartarus.{Events, Ledger}
  alias Tartarus.Agent.Callbacks
  alias Tartarus.Migration.{Arrival, Inbox, Protocol, Source}

  @host :"$tartarus_host"

  # With the host option :hibernate_after, idle agents hibernate (their heap shrinks to what
  # their state needs): a host may then hold millions of them. It is off by default because
  # the timer it arms on every wait costs about a fifth of the migration throughput.
  #
  # The host's server starts agents itself (start/3), monitored from their first instant
  # (spawn_opt's :monitor): no supervisor call and no start-up handshake on the path of a
  # hop or a create. The host's server restarts crashed agents from their snapshots and,
  # when it stops (its terminate/2), kills them all (see Tartarus.Host.Server).
  @doc false
  @spec start(map(), reference(), Tartarus.Envelope.t(), term()) :: {pid(), reference()}
  def start(host, key, env, mode) do
    :erlang.spawn_opt(__MODULE__, :enter, [host, key, env, mode], [
      :monitor | heap_limit(host.opts.max_heap_size)
    ])
  end

  @doc false
  # The same, unmonitored: for a local creator, whose host's server adopts the process
  # (Tartarus.Host.Agents.create_local/4).
  @spec spawn_agent(map(), reference(), Tartarus.Envelope.t(), term()) :: pid()
  def spawn_agent(host, key, env, mode) do
    :erlang.spawn_opt(
      __MODULE__,
      :enter,
      [host, key, env, mode],
      heap_limit(host.opts.max_heap_size)
    )
  end

  defp heap_limit(:infinity), do: []
  defp heap_limit(words), do: [max_heap_size: %{size: words, kill: true, error_logger: false}]

  defp loop_opts(%{opts: %{hibernate_after: :infinity}}), do: []
  defp loop_opts(%{opts: %{hibernate_after: ms}}), do: [hibernate_after: ms]

  # -- start ---------------------------------------------------------------------

  @doc false
  # The new process's entry point (start/4): becomes a gen_server. Spawned plainly (not by
  # proc_lib, whose start-up bookkeeping costs more than the rest of an arrival), it names
  # itself as its own parent: gen_server stops on any {:EXIT, parent, _} message, and anyone
  # can send one; this process stops on its host's signals by the rules of handle_info/2.
  def enter(host, key, env, mode) do
    Process.put(:"$ancestors", [self()])
    Process.put(:"$initial_call", {__MODULE__, :init, 1})

    case init({host, key, env, mode}) do
      {:ok, data} -> :gen_server.enter_loop(__MODULE__, loop_opts(host), data)
      {:ok, data, cont} -> :gen_server.enter_loop(__MODULE__, loop_opts(host), data, cont)
      {:stop, reason} -> exit(reason)
    end
  end

  @impl true
  def init({host, key, env, mode}) do
    Process.put(@host, host)

    data = %{
      host: host,
      env: env,
      key: key,
      paused: nil,
      inbox: Inbox.new(),
      pending: []
    }

    start(data, mode)
  end

  # The agent's init/1 runs after this process started (see handle_continue({:init, _})).
  defp start(data, {:create, args}) do
    {:ok, put_in(data.env.visits, %{data.host.ref => 1}), {:continue, {:init, args}}}
  end

  # `src_pid`: the source agent's process when the prepare came from it (nil for a copy
  # revived from the journal): its commit carries the messages it held.
  defp start(data, {:paused, mig, copy, src, kind, src_pid}),
    do: {:ok, %{data | paused: Arrival.paused(data.host, mig, copy, src, kind, src_pid)}}

  # After a crash (n restarts so far) or, with n = 0, restored from a checkpoint when the
  # host started again on its data directory.
  defp start(data, {:restart, n}) do
    data = crashed_on(data)

    case Ledger.register_resident(data.host, data.env, self()) do
      :ok -> {:ok, data, {:continue, {:arrive, %{ctx(data) | restarts: n}}}}
      {:error, reason} -> {:stop, reason}
    end
  end

  # Restored from a checkpoint: the host's server waits for this word before it answers the
  # restore (so a host comes back with its agents findable).
  defp start(data, :restore) do
    result = start(data, {:restart, 0})
    send(data.host.pid, {:"$tartarus_restored", self()})
    result
  end

  @impl true
  def handle_continue({:init, args}, data) do
    env = data.env

    case Callbacks.run(data, :init, fn -> env.module.init(args) end) do
      {:ok, action, data} ->
        if action?(action),
          do: init_done(action, data),
          # Not an action: the create fails (the agent never runs).
          else: init_failed(data, {:bad_action, action})

      # Answered by the host, which sees the exit.
      {:error, {:callback_timeout, _, _} = reason, data} ->
        {:stop, reason, data}

      {:error, reason, data} ->
        init_failed(data, reason)
    end
  end

  def handle_continue({:arrive, ctx}, data) do
    run(data, :handle_arrival, fn -> data.env.module.handle_arrival(ctx, data.env.state) end)
  end

  defp init_failed(data, reason) do
    created(data, {:error, {:init_failed, reason}})
    {:stop, {:shutdown, {:init_failed, reason}}, data}
  end

  defp action?({:stay, _}), do: true
  defp action?({kind, _, _}) when kind in [:move, :clone, :return, :stop], do: true
  defp action?(_), do: false

  defp init_done(action, data) do
    env = data.env

    case Ledger.register_resident(data.host, env, self()) do
      :ok ->
        arrived(put_state(data, action_state(action)))
        emit(data, %{type: :created, agent: env.id, module: env.module}, created: 1)
        created(data, {:ok, env.id})
        act(action, data)

      {:error, reason} ->
        created(data, {:error, reason})
        {:stop, {:shutdown, {:create_failed, reason}}, data}
    end
  end

  # -- the paused copy (destination side) ---------------------------------------------
  # Tartarus.Migration.Arrival runs the in-doubt copy and, on its commit, makes it the
  # agent; the messages it was handed over are handled before handle_arrival/2.

  @impl true
  def handle_info(msg, %{paused: p} = data) when p != nil do
    case Arrival.step(data, msg) do
      {:paused, data} ->
        {:noreply, data}

      # Messages that reached the agent while it moved are handled first (an agent that
      # moves on at every arrival would otherwise carry them for ever); if one of them makes
      # it leave, the rest travel on with it.
      {:started, data, pending} ->
        handle_pending(pending, data, fn data ->
          ctx = ctx(data)

          run(data, :handle_arrival, fn -> data.env.module.handle_arrival(ctx, data.env.state) end)
        end)

      {:stop, reason, data} ->
        {:stop, reason, data}
    end
  end

  # -- messages --------------------------------------------------------------------

  # Without the host option :durable a message is acknowledged as it is taken, before the
  # agent's code runs; with it, once handled and checkpointed (journaled when the host has a
  # data directory), so an acknowledged change survives SIGKILL and restart.
  def handle_info({:"$tartarus_msg", {pid, _ref} = from, kind, _msg} = m, data)
      when is_pid(pid) and kind in [:post, :request] do
    case Inbox.take(data.inbox, from) do
      {true, inbox} -> handle_msg(m, %{data | inbox: inbox})
      {false, _} -> {:noreply, data}
    end
  end

  # Its host kills it (see the top of this module): an agent that traps exits stops too. The
  # mark in the host's ledger tells the host's signal from a forged message.
  def handle_info({:EXIT, pid, :shutdown} = msg, %{host: %{pid: pid}} = data) do
    if :ets.member(data.host.ledger, {:kill, self()}),
      do: {:stop, :shutdown, data},
      else: user_info(msg, data)
  end

  # A commit (with its hand-over) that came after this process stopped waiting for it (its
  # source was slow): what this process took meanwhile is not taken twice.
  def handle_info({:"$tartarus_commit", _mig, _copy, _notify, {msgs, _}}, data)
      when is_list(msgs) do
    {msgs, inbox} = Inbox.take_new(data.inbox, msgs)
    handle_pending(msgs, %{data | inbox: inbox}, fn data -> {:noreply, data} end)
  end

  # A late reply to a hand-off this agent already gave up on, a commit or answer delivered
  # twice, or a timer that fired as it committed: not for the agent's code.
  def handle_info({:commit_timeout, _}, data), do: {:noreply, data}

  def handle_info(msg, data) when is_tuple(msg) and elem(msg, 0) == :"$tartarus_msg",
    do: dropped(data, msg)

  def handle_info(msg, data) when is_tuple(msg) and tuple_size(msg) > 0 do
    if Protocol.protocol_message?(msg), do: {:noreply, data}, else: user_info(msg, data)
  end

  def handle_info(msg, data), do: user_info(msg, data)

  defp handle_msg({:"$tartarus_msg", {pid, ref}, kind, msg}, data) do
    durable = Map.get(data.host.opts, :durable, false)
    unless durable, do: send(pid, {ref, :delivered})
    bytes = :erlang.external_size(msg)

    emit(data, %{type: :message, agent: data.env.id, bytes: bytes},
      messages: 1,
      message_bytes: bytes
    )

    from = if kind == :request, do: {pid, ref}

    if durable do
      # Unacknowledged until handled: if handling it crashes the agent, the restarted agent
      # tells the sender (and does not take it again) instead of taking it for good.
      key = {:handling, data.env.id}
      :ets.insert(data.host.ledger, {key, {pid, ref}})

      result =
        run(
          data,
          {:handle_message, from},
          fn -> data.env.module.handle_message(msg, from, data.env.state) end,
          {pid, ref}
        )

      case result do
        {:stop, {kind, _, _}, _} when kind in [:error, :exit, :throw] -> :crashed
        _ -> :ets.delete(data.host.ledger, key)
      end

      result
    else
      run(data, {:handle_message, from}, fn ->
        data.env.module.handle_message(msg, from, data.env.state)
      end)
    end
  end

  # After a crash: the message whose handling crashed the agent (host option :durable) is
  # answered with an error and not taken again.
  defp crashed_on(data) do
    case :ets.take(data.host.ledger, {:handling, data.env.id}) do
      [{_, {pid, ref} = from}] ->
        send(pid, {ref, {:failed, :agent_crashed}})
        %{data | inbox: elem(Inbox.take(data.inbox, from), 1)}

      [] ->
        data
    end
  end

  defp user_info(msg, data) do
    if function_exported?(data.env.module, :handle_info, 2) do
      run(data, :handle_info, fn -> data.env.module.handle_info(msg, data.env.state) end)
    else
      {:noreply, data}
    end
  end

  defp dropped(data, _msg) do
    Ledger.count(data.host, :dropped)
    {:noreply, data}
  end

  # -- control (from Tartarus facade) ----------------------------------------------

  @impl true
  def handle_call(_op, from, data) when not Tartarus.Events.is_from(from),
    do: dropped(data, :call)

  def handle_call(_op, _from, %{paused: p} = data) when p != nil do
    {:reply, {:error, :in_transit}, data}
  end

  def handle_call(:info, _from, data), do: {:reply, info(data), data}

  def handle_call({:payload, op}, _from, data) do
    {result, data} = Callbacks.raw(data, fn -> Callbacks.payload_op(op) end)
    {:reply, result, data}
  end

  def handle_call({:move, dest}, from, data) do
    # The destination answers the caller once the agent runs there.
    case Source.attempt(data, :move, dest, from) do
      {:moved, new_pid, data} ->
        # The exit names whose move this was: other callers waiting on this process retry.
        {:stop, {:shutdown, {:migrated, new_pid, from}}, data}

      {:failed, reason, data} ->
        GenServer.reply(from, {:error, reason})
        failed(data, dest, reason)
    end
  end

  def handle_call({:clone, dest}, from, data) do
    # The clone answers the caller once it runs.
    case Source.attempt(data, :clone, dest, from) do
      {:cloned, _clone_id, data} -> {:noreply, data}
      {:failed, reason, data} -> {:reply, {:error, reason}, data}
    end
  end

  # Anything else (from anywhere): answered, counted, never a crash.
  def handle_call(_other, _from, data) do
    {:noreply, data} = dropped(data, :call)
    {:reply, {:error, :unexpected}, data}
  end

  @impl true
  def handle_cast(_other, data), do: dropped(data, :cast)

  # Whatever ends this process with a return value (it moved on, stopped, returned,
  # crashed in a callback): the processes it started with Tartarus.Agent.spawn_link/1 end
  # too. (Killed, it has no say: its host ends them, see Tartarus.Host.Server.)
  @impl true
  def terminate(_reason, data) do
    if Process.get(:"$tartarus_children"), do: Tartarus.Agent.end_children(data.host, self())
  end

  # -- actions -------------------------------------------------------------------

  # `ack`: the sender of a message the host option :durable makes durable before it is
  # acknowledged (nil otherwise). `cb` names the callback for its time budget.
  defp run(data, cb, fun, ack \\ nil) do
    case Callbacks.run(data, cb, fun) do
      {:ok, action, data} ->
        data = checkpoint(data, action, Process.delete(:"$tartarus_checkpoint") == true or ack)
        with {pid, ref} <- ack, do: send(pid, {ref, :delivered})
        act(action, data)

      {:error, reason, data} ->
        Process.delete(:"$tartarus_checkpoint")
        {:stop, reason, data}
    end
  end

  # The state the callback returned, made the agent's snapshot (Tartarus.Agent.checkpoint/0,
  # or a message under the host option :durable). A malformed action changes nothing.
  defp checkpoint(data, action, want)
       when want not in [nil, false] and is_tuple(action) and
              tuple_size(action) in [2, 3] do
    data = put_state(data, action_state(action))
    arrived(data)
    data
  end

  defp checkpoint(data, _action, _want), do: data

  defp act({:stay, s}, data), do: {:noreply, put_state(data, s)}

  defp act({:move, dest, s}, data) do
    data = put_state(data, s)

    case Source.attempt(data, :move, dest) do
      {:moved, new_pid, data} -> {:stop, {:shutdown, {:migrated, new_pid, nil}}, data}
      {:failed, reason, data} -> failed(data, dest, reason)
    end
  end

  defp act({:clone, dest, s}, data) do
    data = put_state(data, s)

    case Source.attempt(data, :clone, dest) do
      {:cloned, _id, data} -> {:noreply, data}
      {:failed, reason, data} -> failed(data, dest, {:clone_failed, reason})
    end
  end

  defp act({:return, result, s}, data) do
    data = put_state(data, s)
    if is_pid(data.env.owner), do: send(data.env.owner, {:tartarus_result, data.env.id, result})
    stop(data, :returned)
  end

  defp act({:stop, reason, s}, data), do: stop(put_state(data, s), reason)
  defp act(other, data), do: {:stop, {:bad_action, other}, data}

  defp stop(data, reason) do
    # No longer resident: the host must not take the exit for a crash to restart from.
    Ledger.forget_resident(data.host, self())
    Tartarus.Host.Persistence.forget(data.host, data.env.id)
    Ledger.gone(data.host, data.env)
    emit(data, %{type: :stopped, agent: data.env.id, reason: reason}, stopped: 1)
    {:stop, {:shutdown, {:stopped, reason}}, data}
  end

  defp failed(data, dest, reason) do
    emit(data, %{type: :move_failed, agent: data.env.id, to: dest, reason: reason}, move_failed: 1)

    run(data, :handle_move_failed, fn ->
      data.env.module.handle_move_failed(dest, reason, ctx(data), data.env.state)
    end)
  end

  # -- reaching a busy agent --------------------------------------------------------
  # Tartarus.Migration.Inbox decides what is taken and what is handed over; this process
  # drains its mailbox into the commit (source) and handles the hand-over first (successor).

  # Handles `msgs` one by one as if they came from the mailbox, then calls `next`; if one
  # of them stops the process (a move), the others are left in data.pending for the
  # hand-over.
  defp handle_pending([], data, next), do: next.(data)

  defp handle_pending([m | rest], data, next) do
    case handle_msg(m, %{data | pending: rest}) do
      {:noreply, data} -> handle_pending(rest, %{data | pending: []}, next)
      other -> other
    end
  end

  # -- helpers ---------------------------------------------------------------------

  defp arrived(data), do: Arrival.snapshot(data)

  defp ctx(data) do
    %{
      host: data.host.ref,
      from: data.env.from,
      hops: data.env.hops,
      clone_of: data.env.clone_of,
      restarts: 0
    }
  end

  defp action_state({_, s}), do: s
  defp action_state({_, _, s}), do: s
  defp action_state(_), do: nil

  defp put_state(data, s), do: %{data | env: %{data.env | state: s}}

  # The creator of this agent, if no one answered it yet (see the top of this module).
  defp created(data, reply) do
    case :ets.take(data.host.ledger, {:creating, data.key}) do
      [{_, from}] -> GenServer.reply(from, reply)
      [] -> :ok
    end
  end

  defp info(data) do
    env = data.env

    %{
      id: env.id,
      name: env.name,
      module: env.module,
      host: data.host.ref,
      home: env.home,
      hops: env.hops,
      static: env.static,
      state: env.state,
      payload: env.payload,
      clone_of: env.clone_of,
      pid: self()
    }
  end

  defp emit(data, event, counts) do
    Events.emit(data.host, Map.put(event, :host, data.host.ref), counts)
  end
end
