defmodule Tartarus.Migration.Arrival do
  @moduledoc false
  # The destination side of a hand-off, in the arriving copy's own process: the paused (in
  # doubt) copy, which runs nothing until it learns its migration's decision
  # (Tartarus.Migration.Protocol.copy_step/2 decides; this module carries out its actions:
  # ask, arm the timer, stash or drop, park, abort), and the commit that makes it the agent
  # (registration, snapshot, the answer to whoever waits for the move, the lazy
  # acknowledgement, the hop time). Tartarus.Agent.Server calls step/2 for every message
  # while paused; on {:started, data, pending} it handles the handed-over messages, then
  # handle_arrival/2.

  require Tartarus.Events
  alias Tartarus.{Events, Ledger}
  alias Tartarus.Migration.{Inbox, Protocol}

  # How long a host waits before it sends the acknowledgements of its arrivals (one batch
  # per source host, see Tartarus.Host.Server).
  @ack_every 200

  @doc false
  # The paused copy's state, as the agent process keeps it (data.paused). `src_pid`: the
  # source agent's process when the prepare came from it (nil for a copy revived from the
  # journal): its commit carries the messages it held.
  @spec paused(map(), term(), term(), term(), :move | :clone, pid() | nil) :: map()
  def paused(host, mig, copy, src, kind, src_pid) do
    c =
      Protocol.copy(mig, copy, src, kind, stash_max: Map.get(host.opts, :paused_stash_max, 1_000))

    timer = Process.send_after(self(), {:commit_timeout, mig}, host.opts.migration_timeout)
    %{c: c, timer: timer, stash: [], src_pid: src_pid, handover: :none}
  end

  @doc false
  # One message to the paused copy: {:paused, data}, {:started, data, pending} (it is the
  # agent now; `pending` are the messages to handle first) or {:stop, reason, data}.
  @spec step(map(), term()) ::
          {:paused, map()} | {:started, map(), list()} | {:stop, term(), map()}
  def step(%{paused: p} = data, msg) do
    event =
      case msg do
        {:commit_timeout, mig} when mig == p.c.mig ->
          :timeout

        _ ->
          case Protocol.classify(msg) do
            {:commit, _, _, _} = commit -> commit
            {:decision, _, _, _} = decision -> decision
            :other -> {:message, msg}
            # Stray hand-off messages (of an earlier attempt) are not for the agent.
            _ -> :ignore
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

    {c, actions} = Protocol.copy_step(p.c, event)
    actions(actions, %{data | paused: %{p | c: c}})
  end

  defp actions([], data), do: {:paused, data}
  defp actions([{:start, notify} | _], data), do: start(data, notify)

  defp actions([:abort | _], data) do
    Tartarus.Host.Persistence.resolved(data.host, data.paused.c.mig, data.paused.c.copy)
    {:stop, {:shutdown, :aborted}, data}
  end

  # Unanswered too long: the host keeps the record (and asks on its behalf); this process and
  # its stash go (the senders waiting on stashed messages time out).
  defp actions([:park | _], data) do
    %{c: c} = data.paused
    :ok = GenServer.call(data.host.pid, {:park, c.mig, c.copy, data.env, c.src, c.kind})
    {:stop, {:shutdown, :parked}, data}
  end

  defp actions([{:ask, src, mig, copy} | rest], data) do
    # The source host's server, found by address each time (the source may have restarted
    # since it sent `prepare`; the directory drops pids of hosts that went down).
    id = Ledger.query_id(data.env, data.paused.c.kind)

    with {:ok, pid} <- Tartarus.Host.whereis(src),
         do: send(pid, Protocol.decision_query(mig, id, copy, self()))

    actions(rest, data)
  end

  defp actions([{:timer, ms} | rest], data) do
    timer = Process.send_after(self(), {:commit_timeout, data.paused.c.mig}, ms)
    actions(rest, %{data | paused: %{data.paused | timer: timer}})
  end

  # Kept and handled once the agent starts (senders wait for delivery, so each sender's
  # order is kept).
  defp actions([{:stash, msg} | rest], data),
    do: actions(rest, %{data | paused: %{data.paused | stash: [msg | data.paused.stash]}})

  # Over the bound: dropped and counted; a sender of a message is told to send it again
  # later (Tartarus.Locator backs off and does), so it queues at its sender, not here.
  defp actions([{:drop, msg} | rest], data) do
    with {:"$tartarus_msg", {pid, tag}, _, _} when is_pid(pid) <- msg,
         do: send(pid, {tag, :retry})

    Ledger.count(data.host, :dropped)
    actions(rest, data)
  end

  # -- the commit: the copy becomes the agent -------------------------------------------

  defp start(%{paused: %{c: c} = p} = data, notify) do
    Process.cancel_timer(p.timer)
    # A move: the source's commit carries the messages it held. If this copy learnt the
    # decision by asking (the commit is late or lost) while the source process lives, wait
    # for that commit before taking anything else (the source may be slow, not gone: taking
    # newer messages first would break a sender's order and the memory of what was taken).
    handover =
      case p.handover do
        :none when c.kind == :move and is_pid(p.src_pid) ->
          await_commit(c.mig, data.host.opts.migration_timeout, p.src_pid)

        other ->
          other
      end

    # Messages that came while paused are new here unless the hand-over says otherwise.
    {msgs, others} =
      Enum.split_with(Enum.reverse(p.stash), &match?({:"$tartarus_msg", _, _, _}, &1))

    Enum.each(others, &send(self(), &1))
    {pending, inbox} = Inbox.arrive(data.inbox, handover, msgs)
    host = data.host
    now = System.system_time(:microsecond)
    hop_us = if data.env.departed_at, do: max(now - data.env.departed_at, 0), else: 0
    hops = if c.kind == :move, do: data.env.hops + 1, else: data.env.hops

    env = %{
      data.env
      | hops: hops,
        from: c.src,
        visits: Map.update(data.env.visits, host.ref, 1, &(&1 + 1))
    }

    data = %{data | env: env, paused: nil, inbox: inbox}

    case Ledger.register_resident(host, env, self()) do
      :ok ->
        snapshot(data)
        :ets.delete_object(host.ledger, {{:arriving, env.id}, self()})
        Tartarus.Host.Persistence.resolved(host, c.mig, c.copy)

        with {pid, _tag} when is_pid(pid) <- notify,
             do: GenServer.reply(notify, if(c.kind == :move, do: :ok, else: {:ok, env.id}))

        # Running: the source host may forget its record of the commit (acknowledged
        # lazily: this host sends its acknowledgements in batches, see Host.Server).
        :ets.insert(host.acks, {c.src, {c.mig, env.id, c.copy}})

        # The first arrival after a flush arms the next (one atomic flag: every arrival of the
        # node's agents touches it, a table key would be a hot spot).
        if :atomics.compare_exchange(host.acks_armed, 1, 0, 1) == :ok,
          do: Process.send_after(host.pid, :"$tartarus_flush_acks", @ack_every)

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

        {:started, data, pending}

      {:error, reason} ->
        {:stop, reason, data}
    end
  end

  # The source's own commit, when the decision came from asking (see start/2).
  defp await_commit(mig, timeout, src_pid) do
    mref = Process.monitor(src_pid)

    receive do
      # The source ended without sending it (it sends the commit before it ends).
      {:DOWN, ^mref, :process, _, _} ->
        nil

      {:"$tartarus_commit", ^mig, _copy, _notify, handover} ->
        Process.demonitor(mref, [:flush])
        handover
    after
      timeout ->
        Process.demonitor(mref, [:flush])
        nil
    end
  end

  @doc false
  # The agent is resident here as `data.env`: that is its arrival snapshot, for restarts
  # after a crash and (with persistence) after the host's restart.
  @spec snapshot(map()) :: :ok
  def snapshot(data) do
    :ets.insert(data.host.ledger, {{:snapshot, data.key}, data.env})
    Tartarus.Host.Persistence.checkpoint(data.host, data.env)
    :ok
  end
end
