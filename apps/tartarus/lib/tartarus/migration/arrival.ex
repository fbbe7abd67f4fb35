defmodule Tartarus.Migration.Arrival do
  @moduledoc false
  # The destination side of a hand-off, in the arriving copy's own process: the paused (in
  # doubt) copy, which runs nothing until it learns its migration's decision
  # (Tartarus.Migration.CopyProtocol.step/2 decides; this module carries out its actions:
  # ask, re-arm its state timeout, stash or drop, park, abort), and the commit that makes it
  # the agent (registration, snapshot, the answer to whoever waits for the move, the lazy
  # acknowledgement, the hop time). Tartarus.Agent.Server (states :paused and
  # :awaiting_commit) calls step/2 for every message and timeout while paused; on
  # {:started, data, pending} it handles the handed-over messages, then handle_arrival/2.

  @behaviour Tartarus.Migration.Executor.Copy

  require Tartarus.Events
  alias Tartarus.{Clock, Events, Ledger}
  alias Tartarus.Migration.{CopyProtocol, Executor, Inbox, Messages}

  # How long a host waits before it sends the acknowledgements of its arrivals (one batch
  # per source host, see Tartarus.Host.Server).
  @ack_every 200

  @doc false
  # The paused copy's state, as the agent process keeps it (data.paused). `src_pid`: the
  # source agent's process when the prepare came from it (nil for a copy revived from the
  # journal): its commit carries the messages it held.
  # Its first state timeout (:commit) is the host's :migration_timeout.
  # `opts`: CopyProtocol.new/5's (`claim: true` for a copy revived from a parked record).
  @spec paused(map(), term(), term(), term(), :move | :clone, pid() | nil, keyword()) :: map()
  def paused(host, mig, copy, src, kind, src_pid, opts \\ []) do
    {stash_max, _bytes} = stash_bound(host)
    opts = [stash_max: stash_max, src_pid: src_pid] ++ opts
    c = CopyProtocol.new(mig, copy, src, kind, opts)
    %{c: c, stash: [], pending: [], await: nil}
  end

  @doc false
  # The one bound on what either end of a hop keeps for later, {count, bytes}: the host
  # options :max_held and :max_held_bytes. The paused copy stashes at most `count` messages
  # (the protocol's `stash_max`, CopyProtocol.new/5); the source, while it hands off, keeps at
  # most `count` events (the messages it hands over with its commit and the other events it
  # postpones) and `bytes` bytes of them (Tartarus.Agent.Server). So a commit's hand-over
  # carries no more than a copy may stash.
  @spec stash_bound(map()) :: {pos_integer(), pos_integer()}
  def stash_bound(host),
    do: {Map.get(host.opts, :max_held, 1_000), Map.get(host.opts, :max_held_bytes, 8_388_608)}

  @doc false
  # One event of the paused copy ({:info, msg} or :timeout, its state timeout):
  # {:paused, data} (it waits on; its state timeout re-armed in data, see timer/2, or as it
  # was), {:await, data} (wait for the source's commit, see awaited/2), {:started, data,
  # pending} (it is the agent now; `pending` are the messages to handle first) or
  # {:stop, reason, data}.
  @spec step(map(), :timeout | {:info, term()}) ::
          {:paused, map()}
          | {:await, map()}
          | {:started, map(), list()}
          | {:stop, term(), map()}
  def step(%{paused: %{c: c}} = data, :timeout), do: run(c, CopyProtocol.timeout(c), data)

  def step(%{paused: %{c: c}} = data, {:info, msg}) do
    case CopyProtocol.event(c, msg) do
      nil -> {:paused, data}
      event -> run(c, event, data)
    end
  end

  defp run(c, event, data) do
    case Executor.copy_event(c, event, data, __MODULE__) do
      {:paused, data} -> {:paused, data}
      {:done, result} -> result
    end
  end

  @doc false
  # While awaiting the commit: {:ok, handover} for the source's commit (its hand-over) or its
  # end without one (nil), :other for anything else (postponed).
  @spec awaited(map(), term()) :: {:ok, term()} | :other
  def awaited(%{paused: %{c: c, await: mref}}, msg) do
    case msg do
      # The source ended without sending it (it sends the commit before it ends).
      {:DOWN, ^mref, :process, _, _} ->
        {:ok, nil}

      _ ->
        case CopyProtocol.event(c, msg) do
          {:handover, handover} -> {:ok, handover}
          nil -> :other
        end
    end
  end

  @doc false
  # The copy that awaited its source's commit becomes the agent, with `handover` (the
  # source's, or nil when it never came): {:started, data, pending} or {:stop, reason, data}.
  @spec finish(map(), term()) :: {:started, map(), list()} | {:stop, term(), map()}
  def finish(%{paused: %{c: c}} = data, handover), do: run(c, {:handover, handover}, data)

  # -- the executor's effects (the paused copy's backend) -----------------------------------
  # The context: the agent process's state.

  @impl Executor.Copy
  def copy_state(data, c), do: %{data | paused: %{data.paused | c: c}}

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

  # A move that learnt its commit by asking while the source process lives: it waits for
  # that commit (Tartarus.Agent.Server, state :awaiting_commit, awaited/2).
  @impl Executor.Copy
  def await(%{paused: p} = data, pid),
    do: {:await, %{data | paused: %{p | await: Process.monitor(pid)}}}

  # -- the commit: the copy becomes the agent -------------------------------------------

  # Messages that came while paused are new here unless the hand-over says otherwise; the
  # hand-over's come first.
  @impl Executor.Copy
  def become(%{paused: %{c: c} = p} = data, handover) do
    if p.await, do: Process.demonitor(p.await, [:flush])

    {msgs, others} =
      Enum.split_with(Enum.reverse(p.stash), &match?({:"$tartarus_msg", _, _, _}, &1))

    Enum.each(others, &send(self(), &1))
    {pending, inbox} = Inbox.arrive(data.inbox, handover, msgs)
    host = data.host
    hops = if c.kind == :move, do: data.env.hops + 1, else: data.env.hops

    env =
      %{data.env | hops: hops, from: c.src}
      |> Tartarus.Envelope.visit(host.ref, Map.get(host.opts, :max_visits, 64))

    %{data | env: env, inbox: inbox, paused: %{p | stash: [], pending: pending, await: nil}}
  end

  @impl Executor.Copy
  def register(data), do: {Ledger.register_resident(data.host, data.env, self()), data}

  @impl Executor.Copy
  def claim(data, mig, copy), do: {Ledger.unpark(data.host, mig, copy), data}

  @impl Executor.Copy
  def put_snapshot(data) do
    Ledger.put_snapshot(data.host, data.key, data.env)
    data
  end

  @impl Executor.Copy
  def checkpoint(data) do
    Tartarus.Host.Persistence.checkpoint(data.host, data.env)
    data
  end

  @impl Executor.Copy
  def drop_arriving(data) do
    Ledger.drop_arriving(data.host, data.env.id, self())
    data
  end

  @impl Executor.Copy
  def resolve(data, mig, copy) do
    Tartarus.Host.Persistence.resolved(data.host, mig, copy)
    data
  end

  # Running: the source host may forget its record of the commit (acknowledged lazily: this
  # host sends its acknowledgements in batches, see Host.Server). The first arrival after a
  # flush arms the next (one atomic flag: every arrival of the node's agents touches it, a
  # table key would be a hot spot).
  @impl Executor.Copy
  def ack(%{host: host} = data, src, mig, copy) do
    :ets.insert(host.acks, {src, {mig, data.env.id, copy}})

    if :atomics.compare_exchange(host.acks_armed, 1, 0, 1) == :ok,
      do: Clock.send_after(Tartarus.Host.server(host), :"$tartarus_flush_acks", @ack_every)

    data
  end

  @impl Executor.Copy
  def arrived(%{host: host, env: env} = data) do
    now = Clock.system_time(:microsecond)
    hop_us = if env.departed_at, do: max(now - env.departed_at, 0), else: 0
    Ledger.record_hop(host, hop_us)

    Events.emit(
      host,
      %{
        type: :arrival,
        host: host.ref,
        agent: env.id,
        from: env.from,
        hop_us: hop_us,
        hops: env.hops
      },
      arrivals: 1
    )

    data
  end

  # The mover is answered last, so that what it reads next (the host's status, its counts
  # and hop statistics) already has this arrival.
  @impl Executor.Copy
  def reply(data, notify, kind) do
    with {pid, _tag} when is_pid(pid) <- notify,
         do: GenServer.reply(notify, if(kind == :move, do: :ok, else: {:ok, data.env.id}))

    data
  end

  @impl Executor.Copy
  def started(%{paused: p} = data, _c), do: {:started, %{data | paused: nil}, p.pending}

  @impl Executor.Copy
  def stop(data, reason), do: {:stop, reason, data}

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
