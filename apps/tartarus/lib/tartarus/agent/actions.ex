defmodule Tartarus.Agent.Actions do
  @moduledoc false
  # What a running agent does: it runs a callback (Tartarus.Agent.Callbacks, within its
  # budget) and carries out the action the callback returned. A move or a clone starts the
  # source side of a hand-off (Tartarus.Migration.Source), after which the agent's state
  # machine waits in :handing_off (Tartarus.Agent.Server); the outcome comes back to
  # handoff_done/3.
  #
  # Every function here returns an outcome, never a state: {:run, data, actions} (the agent
  # runs on; `actions` are gen_statem actions, replies), {:hand_off, data} (a hand-off
  # started: the source waits for its destination) or {:stop, reason, data}. The agent's
  # state machine (Tartarus.Agent.Server, transition/1) alone turns outcomes into states, so
  # the same code serves a callback run while running and one run when a hand-off failed.

  require Tartarus.Events
  alias Tartarus.{Events, Ledger}
  alias Tartarus.Agent.Callbacks
  alias Tartarus.Migration.{Arrival, Inbox, Source}

  # -- creation ----------------------------------------------------------------------

  @doc false
  # The agent's init/1, after its process started (Tartarus.Agent.Server, :running).
  def init(data, args) do
    env = data.env

    case Callbacks.run(data, :init, fn -> env.module.init(args) end) do
      # (init_done/2 makes the state it returns the snapshot: a checkpoint asked is one.)
      {:ok, action, data, _checkpoint?} ->
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

  defp init_failed(data, reason) do
    created(data, {:error, {:init_failed, reason}})
    {:stop, {:shutdown, {:init_failed, reason}}, data}
  end

  defp journaled(:ok, _data), do: :ok

  defp journaled(error, data) do
    Ledger.forget_resident(data.host, self())
    error
  end

  defp action?({:stay, _}), do: true
  defp action?({kind, _, _}) when kind in [:move, :clone, :return, :stop], do: true
  defp action?(_), do: false

  defp init_done(action, data) do
    env = data.env

    with :ok <- Ledger.register_resident(data.host, env, self()),
         # Not created unless journaled (a full disk: {:error, {:journal, :enospc}}).
         :ok <- journaled(Arrival.snapshot(put_state(data, action_state(action))), data) do
      emit(data, %{type: :created, agent: env.id, module: env.module}, created: 1)
      created(data, {:ok, env.id})
      act(action, data)
    else
      {:error, reason} ->
        created(data, {:error, reason})
        {:stop, {:shutdown, {:create_failed, reason}}, data}
    end
  end

  # The creator of this agent, if no one answered it yet (Tartarus.Agent.Server, top).
  defp created(data, reply) do
    case Ledger.take_creator(data.host, data.key) do
      {:ok, from} -> GenServer.reply(from, reply)
      :error -> :ok
    end
  end

  @doc false
  # handle_arrival/2: after an arrival (and the messages handed over), a restart or a restore.
  def arrival(data, ctx \\ nil) do
    ctx = ctx || ctx(data)
    run(data, :handle_arrival, fn -> data.env.module.handle_arrival(ctx, data.env.state) end)
  end

  # -- messages ------------------------------------------------------------------------

  # A :message event carries the message itself up to this many bytes (external size).
  @message_shown 256

  @doc false
  # A message of Tartarus.post/request/cast, taken (once: Tartarus.Migration.Inbox.running/2,
  # from the mailbox, or handed over by the agent's previous process or a late commit).
  #
  # Without the host option :durable a message is acknowledged as it is taken, before the
  # agent's code runs; with it, once handled and checkpointed (journaled when the host has a
  # data directory), so an acknowledged change survives SIGKILL and restart.
  def handle({:"$tartarus_msg", {pid, ref}, kind, msg}, data) do
    durable = Map.get(data.host.opts, :durable, false)
    unless durable, do: send(pid, {ref, :delivered})
    bytes = :erlang.external_size(msg)

    # The sender's process (a watcher such as the dashboard names the agent it is) and, when
    # small, the message itself: a reference to a term already sized, copied only to
    # subscribers.
    event = %{
      type: :message,
      agent: data.env.id,
      bytes: bytes,
      kind: kind,
      sender: pid,
      message: if(bytes <= @message_shown, do: msg)
    }

    emit(data, event,
      messages: 1,
      message_bytes: bytes
    )

    from = if kind == :request, do: {pid, ref}
    handle = fn -> data.env.module.handle_message(msg, from, data.env.state) end

    if durable do
      # Unacknowledged until handled: if handling it crashes the agent, the restarted agent
      # tells the sender (and does not take it again) instead of taking it for good.
      Ledger.put_handling(data.host, data.env.id, {pid, ref})
      result = run(data, {:handle_message, from}, handle, {pid, ref})

      case result do
        {:stop, {kind, _, _}, _} when kind in [:error, :exit, :throw] -> :crashed
        _ -> Ledger.drop_handling(data.host, data.env.id)
      end

      result
    else
      run(data, {:handle_message, from}, handle)
    end
  end

  @doc false
  # After a crash: the message whose handling crashed the agent (host option :durable) is
  # answered with an error and not taken again.
  def crashed_on(data) do
    case Ledger.take_handling(data.host, data.env.id) do
      {:ok, {pid, ref} = from} ->
        send(pid, {ref, {:failed, :agent_crashed}})
        %{data | inbox: elem(Inbox.take(data.inbox, from), 1)}

      :error ->
        data
    end
  end

  @doc false
  # Any other message: the agent's handle_info/2 if it has one.
  def info(msg, data) do
    if function_exported?(data.env.module, :handle_info, 2) do
      run(data, :handle_info, fn -> data.env.module.handle_info(msg, data.env.state) end)
    else
      running(data)
    end
  end

  @doc false
  # Junk (from anywhere): counted, never a crash.
  def dropped(data) do
    Ledger.count(data.host, :dropped)
    running(data)
  end

  # -- control (from the Tartarus facade) -------------------------------------------------

  @doc false
  def call(:info, from, data), do: running(data, [{:reply, from, info(data)}])

  def call({:payload, op}, from, data) do
    {result, data, _checkpoint?} = Callbacks.raw(data, fn -> Callbacks.payload_op(op) end)
    running(data, [{:reply, from, result}])
  end

  # The destination answers the caller once the agent runs there (a move), the clone once
  # it runs (a clone).
  def call({kind, dest}, from, data) when kind in [:move, :clone],
    do: hand_off(data, kind, dest, {:call, from})

  # Anything else (from anywhere): answered, counted, never a crash.
  def call(_other, from, data) do
    Ledger.count(data.host, :dropped)
    running(data, [{:reply, from, {:error, :unexpected}}])
  end

  # -- actions ---------------------------------------------------------------------------

  @doc false
  # Runs callback `cb` (`fun`) and carries out its action. `ack`: the sender of a message
  # the host option :durable makes durable before it is acknowledged (nil otherwise).
  def run(data, cb, fun, ack \\ nil) do
    case Callbacks.run(data, cb, fun) do
      {:ok, action, new, checkpoint?} ->
        want = checkpoint? or ack

        case checkpoint(new, action, want, data.env) do
          {:ok, new} ->
            with {pid, ref} <- ack, do: send(pid, {ref, :delivered})
            act(action, new)

          # A durable message whose state could not be journaled (a full disk): refused to
          # its sender, and the agent goes on from the state before it.
          {{:error, reason}, _new} when ack != nil ->
            {pid, ref} = ack
            send(pid, {ref, {:failed, reason}})
            running(data)

          {_error, new} ->
            act(action, new)
        end

      {:error, reason, data} ->
        {:stop, reason, data}
    end
  end

  # The state the callback returned, made the agent's snapshot (Tartarus.Agent.checkpoint/0,
  # or a message under the host option :durable). A malformed action changes nothing.
  # {:ok | {:error, _}, data}. A durable message that changed nothing (a read) writes
  # nothing: the snapshot holds that state already (so reads are served on a full disk).
  defp checkpoint(data, action, want, before)
       when want not in [nil, false] and is_tuple(action) and tuple_size(action) in [2, 3] do
    data = put_state(data, action_state(action))

    if is_tuple(want) and data.env == before,
      do: {:ok, data},
      else: {Arrival.snapshot(data), data}
  end

  defp checkpoint(data, _action, _want, _before), do: {:ok, data}

  defp act({:stay, s}, data), do: running(put_state(data, s))

  defp act({kind, dest, s}, data) when kind in [:move, :clone],
    do: hand_off(put_state(data, s), kind, dest, :act)

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

  # -- hand-offs -----------------------------------------------------------------------

  # Starts a move or a clone (Tartarus.Migration.Source): `by` is :act (the agent's action)
  # or {:call, from} (Tartarus.move/2, Tartarus.clone/2). While the destination answers, the
  # agent is :handing_off (Tartarus.Agent.Server keeps what else arrives meanwhile).
  defp hand_off(data, kind, dest, by) do
    case Source.attempt(data, kind, dest, {kind, dest, by}) do
      {:wait, data} ->
        {:hand_off, data}

      {:failed, reason, data} ->
        handoff_done({:failed, reason}, {kind, dest, by}, data)
    end
  end

  @doc false
  # The outcome of a hand-off for whoever started it (`{kind, dest, by}`, see hand_off/4).
  # A move that committed ends this process: the exit names whose move it was (other
  # callers waiting on this process retry).
  def handoff_done({:moved, new_pid}, {:move, _dest, by}, data) do
    from =
      case by do
        {:call, from} -> from
        :act -> nil
      end

    {:stop, {:shutdown, {:migrated, new_pid, from}}, data}
  end

  def handoff_done({:cloned, _id}, _clone, data), do: running(data)

  def handoff_done({:failed, reason}, {:move, dest, {:call, from}}, data) do
    GenServer.reply(from, {:error, reason})
    failed(data, dest, reason)
  end

  def handoff_done({:failed, reason}, {:clone, _dest, {:call, from}}, data) do
    GenServer.reply(from, {:error, reason})
    running(data)
  end

  def handoff_done({:failed, reason}, {:move, dest, :act}, data), do: failed(data, dest, reason)

  def handoff_done({:failed, reason}, {:clone, dest, :act}, data),
    do: failed(data, dest, {:clone_failed, reason})

  defp failed(data, dest, reason) do
    emit(data, %{type: :move_failed, agent: data.env.id, to: dest, reason: reason}, move_failed: 1)

    run(data, :handle_move_failed, fn ->
      data.env.module.handle_move_failed(dest, reason, ctx(data), data.env.state)
    end)
  end

  # -- helpers -------------------------------------------------------------------------

  defp running(data, actions \\ []), do: {:run, data, actions}

  @doc false
  # What Tartarus.Agent.Callbacks' handle_arrival/2 and handle_move_failed/4 get.
  def ctx(data) do
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
