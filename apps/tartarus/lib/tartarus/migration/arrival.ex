defmodule Tartarus.Migration.Arrival do
  @moduledoc false
  # The destination side of a hand-off, in the arriving copy's own process: the paused (in
  # doubt) copy, which runs nothing until it learns its migration's decision
  # (Tartarus.Migration.Protocol.copy_step/2 decides; this module carries out its actions:
  # ask, re-arm its state timeout, stash or drop, park, abort), and the commit that makes it
  # the agent (registration, snapshot, the answer to whoever waits for the move, the lazy
  # acknowledgement, the hop time). Tartarus.Agent.Server (states :paused and
  # :awaiting_commit) calls step/2 for every message and timeout while paused; on
  # {:started, data, pending} it handles the handed-over messages, then handle_arrival/2.

  @behaviour Tartarus.Migration.Executor.Copy

  require Tartarus.Events
  alias Tartarus.{Clock, Events, Ledger}
  alias Tartarus.Migration.{Executor, Inbox, Messages, Protocol}

  # How long a host waits before it sends the acknowledgements of its arrivals (one batch
  # per source host, see Tartarus.Host.Server).
  @ack_every 200

  @doc false
  # The paused copy's state, as the agent process keeps it (data.paused). `src_pid`: the
  # source agent's process when the prepare came from it (nil for a copy revived from the
  # journal): its commit carries the messages it held.
  # Its first state timeout (:commit) is the host's :migration_timeout.
  @spec paused(map(), term(), term(), term(), :move | :clone, pid() | nil) :: map()
  def paused(host, mig, copy, src, kind, src_pid) do
    {stash_max, _bytes} = stash_bound(host)
    c = Protocol.copy(mig, copy, src, kind, stash_max: stash_max)
    %{c: c, stash: [], src_pid: src_pid, handover: :none, notify: nil, await: nil}
  end

  @doc false
  # The one bound on what either end of a hop keeps for later, {count, bytes}: the host
  # options :max_held and :max_held_bytes. The paused copy stashes at most `count` messages
  # (the protocol's `stash_max`, Protocol.copy/5); the source, while it hands off, keeps at
  # most `count` events (the messages it hands over with its commit and the other events it
  # postpones) and `bytes` bytes of them (Tartarus.Agent.Server). So a commit's hand-over
  # carries no more than a copy may stash.
  @spec stash_bound(map()) :: {pos_integer(), pos_integer()}
  def stash_bound(host),
    do: {Map.get(host.opts, :max_held, 1_000), Map.get(host.opts, :max_held_bytes, 8_388_608)}

  @doc false
  # One event of the paused copy ({:info, msg} or :timeout, its state timeout):
  # {:paused, data} (it waits on; its state timeout re-armed in data, see timer/2, or as it
  # was), {:await, data} (wait for the source's commit, see start/2), {:started, data,
  # pending} (it is the agent now; `pending` are the messages to handle first) or
  # {:stop, reason, data}.
  @spec step(map(), :timeout | {:info, term()}) ::
          {:paused, map()}
          | {:await, map()}
          | {:started, map(), list()}
          | {:stop, term(), map()}
  def step(%{paused: p} = data, event) do
    {event, msg} =
      case event do
        :timeout ->
          {:timeout, nil}

        {:info, msg} ->
          case Messages.classify(msg) do
            {:commit, _, _, _} = commit -> {commit, msg}
            {:decision, _, _, _} = decision -> {decision, msg}
            :other -> {{:message, msg}, msg}
            # Stray hand-off messages (of an earlier attempt) are not for the agent.
            _ -> {:ignore, msg}
          end
      end

    # The source's own commit carries its hand-over of messages (see start/2).
    p =
      case {event, msg} do
        {{:commit, mig, copy, _}, {_, _, _, _, handover}}
        when mig == p.c.mig and copy == p.c.copy ->
          %{p | handover: handover}

        _ ->
          p
      end

    case Executor.copy_event(p.c, event, %{data | paused: p}, __MODULE__) do
      {:paused, data} -> {:paused, data}
      {:done, result} -> result
    end
  end

  # -- the executor's effects (the paused copy's backend) -----------------------------------
  # The context: the agent process's state.

  @impl Executor.Copy
  def copy_state(data, c), do: %{data | paused: %{data.paused | c: c}}

  @impl Executor.Copy
  def start(data, _c, notify), do: start(data, notify)

  @impl Executor.Copy
  def abort(data, c) do
    Tartarus.Host.Persistence.resolved(data.host, c.mig, c.copy)
    {:stop, {:shutdown, :aborted}, data}
  end

  # Unanswered too long: the host keeps the record (and asks on its behalf); this process and
  # its stash go (the senders waiting on stashed messages time out).
  @impl Executor.Copy
  def park(data, c) do
    :ok =
      GenServer.call(
        Tartarus.Host.server(data.host),
        {:park, c.mig, c.copy, data.env, c.src, c.kind}
      )

    {:stop, {:shutdown, :parked}, data}
  end

  # The source host's server, found by address each time (the source may have restarted
  # since it sent `prepare`; the directory drops pids of hosts that went down).
  @impl Executor.Copy
  def ask(data, src, mig, copy) do
    id = Ledger.query_id(data.env, data.paused.c.kind)

    with {:ok, pid} <- Tartarus.Host.whereis(src),
         do: send(pid, Messages.decision_query(mig, id, copy, self()))

    data
  end

  # The paused copy's state timeout (:commit), re-armed (Tartarus.Agent.Server's timer).
  @impl Executor.Copy
  def timer(data, ms), do: Tartarus.Agent.StateTimer.arm(data, :paused, ms)

  # Kept and handled once the agent starts (senders wait for delivery, so each sender's
  # order is kept).
  @impl Executor.Copy
  def stash(data, msg), do: %{data | paused: %{data.paused | stash: [msg | data.paused.stash]}}

  # Over the bound: dropped and counted; a sender of a message is told to send it again
  # later (Tartarus.Locator backs off and does), so it queues at its sender, not here.
  @impl Executor.Copy
  def drop(data, msg) do
    with {:"$tartarus_msg", {pid, tag}, _, _} when is_pid(pid) <- msg,
         do: send(pid, {tag, :retry})

    Ledger.count(data.host, :dropped)
    data
  end

  # -- the commit: the copy becomes the agent -------------------------------------------

  # A move: the source's commit carries the messages it held. If this copy learnt the
  # decision by asking (the commit is late or lost) while the source process lives, it waits
  # for that commit (state :awaiting_commit, see awaited/2) before taking anything else (the
  # source may be slow, not gone: taking newer messages first would break a sender's order
  # and the memory of what was taken).
  defp start(%{paused: %{c: c} = p} = data, notify) do
    p = %{p | notify: notify}

    if p.handover == :none and c.kind == :move and is_pid(p.src_pid) do
      {:await, %{data | paused: %{p | await: Process.monitor(p.src_pid)}}}
    else
      finish(%{data | paused: p}, p.handover)
    end
  end

  @doc false
  # While awaiting the commit: {:ok, handover} for the source's commit (its hand-over) or its
  # end without one (nil), :other for anything else (postponed).
  @spec awaited(map(), term()) :: {:ok, term()} | :other
  def awaited(%{paused: %{c: %{mig: mig}, await: mref}}, msg) do
    case msg do
      {:"$tartarus_commit", ^mig, _copy, _notify, handover} -> {:ok, handover}
      # The source ended without sending it (it sends the commit before it ends).
      {:DOWN, ^mref, :process, _, _} -> {:ok, nil}
      _ -> :other
    end
  end

  @doc false
  # The copy becomes the agent, with `handover` (the source's, or nil when it never came).
  @spec finish(map(), term()) :: {:started, map(), list()} | {:stop, term(), map()}
  def finish(%{paused: %{c: c} = p} = data, handover) do
    if p.await, do: Process.demonitor(p.await, [:flush])
    notify = p.notify

    # Messages that came while paused are new here unless the hand-over says otherwise.
    {msgs, others} =
      Enum.split_with(Enum.reverse(p.stash), &match?({:"$tartarus_msg", _, _, _}, &1))

    Enum.each(others, &send(self(), &1))
    {pending, inbox} = Inbox.arrive(data.inbox, handover, msgs)
    host = data.host
    now = Clock.system_time(:microsecond)
    hop_us = if data.env.departed_at, do: max(now - data.env.departed_at, 0), else: 0
    hops = if c.kind == :move, do: data.env.hops + 1, else: data.env.hops

    env =
      %{data.env | hops: hops, from: c.src}
      |> Tartarus.Envelope.visit(host.ref, Map.get(host.opts, :max_visits, 64))

    data = %{data | env: env, paused: nil, inbox: inbox}

    case Ledger.register_resident(host, env, self()) do
      :ok ->
        snapshot(data)
        Ledger.drop_arriving(host, env.id, self())
        Tartarus.Host.Persistence.resolved(host, c.mig, c.copy)

        # Running: the source host may forget its record of the commit (acknowledged
        # lazily: this host sends its acknowledgements in batches, see Host.Server).
        :ets.insert(host.acks, {c.src, {c.mig, env.id, c.copy}})

        # The first arrival after a flush arms the next (one atomic flag: every arrival of the
        # node's agents touches it, a table key would be a hot spot).
        if :atomics.compare_exchange(host.acks_armed, 1, 0, 1) == :ok,
          do: Clock.send_after(Tartarus.Host.server(host), :"$tartarus_flush_acks", @ack_every)

        Ledger.record_hop(host, hop_us)

        Events.emit(
          host,
          %{
            type: :arrival,
            host: host.ref,
            agent: env.id,
            from: c.src,
            hop_us: hop_us,
            hops: hops
          },
          arrivals: 1
        )

        # The mover is answered last, so that what it reads next (the host's status, its
        # counts and hop statistics) already has this arrival.
        with {pid, _tag} when is_pid(pid) <- notify,
             do: GenServer.reply(notify, if(c.kind == :move, do: :ok, else: {:ok, env.id}))

        {:started, data, pending}

      {:error, reason} ->
        {:stop, reason, data}
    end
  end

  @doc false
  # The agent is resident here as `data.env`: that is its arrival snapshot, for restarts
  # after a crash and (with persistence) after the host's restart. :ok, or the journal's
  # error when it could not be written (the ledger's snapshot is taken all the same).
  @spec snapshot(map()) :: :ok | {:error, {:journal, term()}}
  def snapshot(data) do
    Ledger.put_snapshot(data.host, data.key, data.env)
    Tartarus.Host.Persistence.checkpoint(data.host, data.env)
  end
end
