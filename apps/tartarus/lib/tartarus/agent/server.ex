defmodule Tartarus.Agent.Server do
  @moduledoc false
  # The process of one agent: a :gen_statem with four states.
  #
  #   * :running: the agent's callbacks run (Tartarus.Agent.Actions carries out what they
  #     return, within their budgets: Tartarus.Agent.Callbacks);
  #   * :handing_off: the source side of a move or clone (Tartarus.Migration.Source) waits
  #     for the destination; the agent's messages that arrive meanwhile are kept in
  #     data.held, every other event (calls, casts, other messages) is postponed (gen_statem
  #     keeps it and takes it again in the next state); together bounded in count and bytes
  #     by the stash bound of the hop (Tartarus.Migration.Arrival.stash_bound/1), the
  #     overflow refused to its senders (Tartarus.Agent.Held). If the hand-off fails, the held messages
  #     are handled afterwards in their order, then the postponed events; if the move
  #     commits, the agent's messages go with the commit (Tartarus.Migration.Inbox) and the
  #     rest is left to its senders' retries. The deadline is a state timeout;
  #   * :paused: the in-doubt copy at a destination (Tartarus.Migration.Arrival); it runs
  #     nothing until it learns its migration's decision (state timeout: ask the source);
  #   * :awaiting_commit: a paused copy that learnt its move committed by asking while the
  #     source process lives: it waits for the source's commit (which carries the messages
  #     the source held) before taking anything else (everything else is postponed).
  #
  # The hand-off's decisions are Tartarus.Migration.Protocol's (its moduledoc is the
  # specification); Tartarus.Migration.Executor orders their effects. No receive waits
  # inside a callback: the only receive outside gen_statem's loop is the non-blocking drain
  # of the mailbox into a committed move's hand-over (Source.handover/1).
  #
  # Callbacks never block the host. The agent's code (init/1 included) runs only in this
  # process, after it started (the host spawns it and returns at once, see start/4).
  # A create is answered by whoever settles it first, through an ETS entry
  # {{:creating, key}, from} the host writes before it starts the process (:ets.take makes
  # the answer exactly-once): this process once init/1 returned and the agent is resident
  # ({:ok, id}) or failed ({:error, {:init_failed, _}}), else the host when the process
  # goes down ({:error, {:callback_timeout, :init, ms}} or {:error, {:init_failed, reason}}).
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
  #
  # State timeouts are timers of Tartarus.Clock (so that a network in virtual time times its
  # hand-offs in that time) with gen_statem's semantics (Tartarus.Agent.StateTimer): data.timer
  # is {timer, state} for the one armed, or nil; every way out of :handing_off, :paused and
  # :awaiting_commit cancels it, and a stale one's message is ignored in any state.
  @behaviour :gen_statem
  require Tartarus.Events

  alias Tartarus.Agent.{Actions, Held, StateTimer}
  alias Tartarus.Ledger
  alias Tartarus.Migration.{Arrival, Inbox, Source}

  @timeout :"$tartarus_state_timeout"

  # With the host option :hibernate_after, idle agents hibernate (their heap shrinks to what
  # their state needs): a host may then hold millions of them. It is off by default because
  # the timer it arms on every wait costs about a fifth of the migration throughput.
  #
  # The host's server starts agents itself (start/4), monitored from their first instant
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

  @doc false
  # The calling process becomes the agent (the paused copy its own admission made,
  # Tartarus.Host.Arrivals): the same process flags as start/4's, at normal priority (the
  # admission ran at high), then enter/4. Never returns.
  @spec become(map(), reference(), Tartarus.Envelope.t(), term()) :: no_return()
  def become(host, key, env, mode) do
    Process.flag(:priority, :normal)
    for {flag, value} <- heap_limit(host.opts.max_heap_size), do: Process.flag(flag, value)
    enter(host, key, env, mode)
  end

  # The mailbox lives off the heap: what others send an agent faster than it takes it does
  # not count against its :max_heap_size (a flood of messages cannot get it killed and
  # restarted from its snapshot); it takes each and, while it hands off, refuses what is
  # beyond its bound (hold/2).
  defp heap_limit(:infinity), do: [message_queue_data: :off_heap]

  defp heap_limit(words),
    do: [
      message_queue_data: :off_heap,
      max_heap_size: %{size: words, kill: true, error_logger: false}
    ]

  defp loop_opts(%{opts: %{hibernate_after: :infinity}}), do: []
  defp loop_opts(%{opts: %{hibernate_after: ms}}), do: [hibernate_after: ms]

  # -- start ---------------------------------------------------------------------

  @doc false
  # The new process's entry point (start/4): becomes a gen_statem. Spawned plainly, not by
  # proc_lib (the deviation agent_process_test.exs pins: :sys works on it, its crash is
  # logged once, by its host, with no crash report of proc_lib's, and its host's stop or
  # kill ends it), it names its parent itself: its host's warden (Tartarus.Host.Warden), the
  # process that ends it when the host stops (with :kill: it never sends an agent an exit
  # message). gen_statem stops on any message {:EXIT, parent, _}, whoever sent it: the
  # parent must be a process nobody names in such a message by accident. It was the agent
  # itself once, and a stray {:EXIT, agent, reason} stopped the agent with that reason. This
  # process stops on its host's server's signals by the rules of :running.
  def enter(host, key, env, mode) do
    Process.put(:"$ancestors", [host.warden])
    Process.put(:"$initial_call", {__MODULE__, :init, 1})

    case init({host, key, env, mode}) do
      {:ok, state, data, actions} ->
        :gen_statem.enter_loop(__MODULE__, loop_opts(host), state, data, actions)

      {:stop, reason} ->
        exit(reason)
    end
  end

  @impl true
  def callback_mode, do: :handle_event_function

  @impl true
  def init({host, key, env, mode}) do
    data = %{
      # What it keeps while it hands off (Tartarus.Agent.Held).
      held: [],
      held_size: {0, 0},
      postponed: {0, 0},
      host: host,
      env: env,
      key: key,
      paused: nil,
      inbox: Inbox.new(),
      pending: [],
      handoff: nil,
      # True once the agent's code started a process with Tartarus.Agent.spawn_link/1.
      children: false,
      timer: nil
    }

    start(data, mode)
  end

  # The agent's init/1 runs after this process started (the first event).
  defp start(data, {:create, args}) do
    env = %{data.env | visits: %{}, visit_order: []} |> Tartarus.Envelope.visit(data.host.ref, 1)

    {:ok, :running, %{data | env: env}, [{:next_event, :internal, {:init, args}}]}
  end

  # `src_pid`: the source agent's process when the prepare came from it (nil for a copy
  # revived from the journal): its commit carries the messages it held.
  defp start(data, {:paused, mig, copy, src, kind, src_pid}),
    do: start_paused(data, Arrival.paused(data.host, mig, copy, src, kind, src_pid))

  # Revived by its host from a parked record, which it takes itself before it acts on its
  # decision (CopyProtocol.new/5's :claim).
  defp start(data, {:revived, mig, copy, src, kind}),
    do: start_paused(data, Arrival.paused(data.host, mig, copy, src, kind, nil, claim: true))

  # After a crash (n restarts so far) or, with n = 0, restored from a checkpoint when the
  # host started again on its data directory.
  defp start(data, {:restart, n}) do
    data = Actions.crashed_on(data)

    case Ledger.register_resident(data.host, data.env, self()) do
      :ok ->
        {:ok, :running, data,
         [{:next_event, :internal, {:arrival, %{Actions.ctx(data) | restarts: n}}}]}

      {:error, reason} ->
        {:stop, reason}
    end
  end

  # Restored from a checkpoint: the host's server waits for this word before it answers the
  # restore (so a host comes back with its agents findable).
  defp start(data, :restore) do
    result = start(data, {:restart, 0})
    send(data.host.pid, {:"$tartarus_restored", self()})
    result
  end

  # -- state timeouts (see the top of this module) --------------------------------------

  @impl true
  def handle_event(:info, {:timeout, t, {@timeout, what}}, state, %{timer: {t, state}} = data),
    do: timed_out(what, state, %{data | timer: nil})

  def handle_event(:info, {:timeout, _, {@timeout, _}}, _state, _data), do: :keep_state_and_data

  # -- :running ------------------------------------------------------------------------

  # A message handed over (by the agent's previous process or a late commit): already taken.
  def handle_event(:internal, {:pending, m}, :running, data),
    do: transition(Actions.handle(m, data))

  def handle_event(:internal, {:init, args}, :running, data),
    do: transition(Actions.init(data, args))

  def handle_event(:internal, {:arrival, ctx}, :running, data),
    do: transition(Actions.arrival(data, ctx))

  # Its host kills it (see the top of this module): an agent that traps exits stops too. The
  # mark in the host's ledger tells the host's signal from a forged message. The host's
  # server may have been restarted since this process started: the current one counts.
  def handle_event(:info, {:EXIT, pid, :shutdown} = msg, :running, data)
      when pid == data.host.pid or node(pid) == node() do
    if (pid == data.host.pid or pid == Tartarus.Host.server(data.host)) and
         Ledger.kill_marked?(data.host, self()),
       do: {:stop, :shutdown, data},
       else: transition(Actions.info(msg, data))
  end

  # The agent's messages (taken once), a commit that came after this process stopped
  # waiting for it, junk, late protocol messages: Tartarus.Migration.Inbox.running/2 says which.
  def handle_event(:info, msg, :running, data) do
    case Inbox.running(data.inbox, msg) do
      {:handle, m, inbox} -> transition(Actions.handle(m, %{data | inbox: inbox}))
      {:pending, msgs, inbox} -> {:keep_state, %{data | inbox: inbox}, pending(msgs)}
      :junk -> transition(Actions.dropped(data))
      :other -> transition(Actions.info(msg, data))
      _taken_or_protocol -> :keep_state_and_data
    end
  end

  def handle_event({:call, from}, _op, _state, data) when not Tartarus.Events.is_from(from),
    do: Actions.dropped(data) |> keep_state()

  def handle_event({:call, from}, op, :running, data),
    do: transition(Actions.call(op, from, data))

  def handle_event(:cast, _msg, :running, data), do: transition(Actions.dropped(data))

  # -- :handing_off --------------------------------------------------------------------
  # Tartarus.Migration.Source reads the destination's answers; the agent's messages wait in
  # data.held, everything else is postponed (see the top of this module).

  # The rest of a hand-over being handled when the agent left again: still taken, not handled.
  def handle_event(:internal, {:pending, m}, :handing_off, data),
    do: {:keep_state, %{data | pending: data.pending ++ [m]}}

  def handle_event(type, content, :handing_off, data) do
    case Source.route(data, {type, content}) do
      {:step, event} -> handoff(data, event)
      {:held, data} -> {:keep_state, data}
      {:postponed, data} -> {:keep_state, data, [:postpone]}
      _taken_or_refused -> :keep_state_and_data
    end
  end

  # -- :paused and :awaiting_commit ------------------------------------------------------------------

  def handle_event(:info, msg, :paused, data), do: paused(data, {:info, msg})

  def handle_event(:info, msg, :awaiting_commit, data) do
    case Arrival.awaited(data, msg) do
      {:ok, handover} -> started(Arrival.finish(StateTimer.cancel(data), handover))
      :other -> {:keep_state_and_data, [:postpone]}
    end
  end

  def handle_event({:call, from}, _op, state, _data) when state in [:paused, :awaiting_commit],
    do: {:keep_state_and_data, [{:reply, from, {:error, :in_transit}}]}

  def handle_event(_type, _content, :awaiting_commit, _data),
    do: {:keep_state_and_data, [:postpone]}

  def handle_event(_type, _content, _paused, data), do: Actions.dropped(data) |> keep_state()

  # Whatever ends this process with a return value (it moved on, stopped, returned,
  # crashed in a callback): the processes it started with Tartarus.Agent.spawn_link/1 end
  # too. (Killed, it has no say: its host ends them, see Tartarus.Host.Server.)
  #
  # A crash's reason is also left in the host's ledger ({:exit_reason, pid}): a server that
  # adopts this process only after it ended (a local create, a server restarted meanwhile)
  # sees :noproc, and reads the reason there.
  @impl true
  def terminate(reason, _state, data) do
    if data.children, do: Tartarus.Agent.end_children(data.host, self())
    # Ended by its own choice: no longer one of the host's agents for admission, whatever
    # the host's server's backlog (a moving agent left already: Migration.Source.leave/1).
    if stopped?(reason), do: Ledger.uncount_proc(data.host, self())

    unless reason in [:normal, :shutdown] or match?({:shutdown, _}, reason),
      do: Ledger.put_exit_reason(data.host, self(), reason)
  end

  # -- helpers ---------------------------------------------------------------------------

  defp stopped?({:shutdown, {:migrated, _, _}}), do: false
  defp stopped?({:shutdown, _}), do: true
  defp stopped?(reason), do: reason in [:normal, :shutdown]

  # A state timeout that still counts (the handler above): its state's timeout event.
  defp timed_out(:handoff, :handing_off, data), do: handoff(data, :timeout)
  defp timed_out(:commit, :paused, data), do: paused(data, :timeout)
  defp timed_out(:commit, :awaiting_commit, data), do: started(Arrival.finish(data, nil))
  defp timed_out(_what, _state, _data), do: :keep_state_and_data

  # One event of the source side: wait on, or the outcome for whoever started the hand-off;
  # if it failed, what was held is handled now, in its order (after the agent's
  # handle_move_failed/4, which may start another hand-off: then it waits again).
  defp handoff(data, event) do
    case Source.step(data, event) do
      {:wait, data} ->
        {:keep_state, data}

      {outcome, by, data} ->
        # :handing_off ends here (whatever comes next: another hand-off arms its own).
        {events, postponed, left} = Held.release(StateTimer.cancel(data))
        result = Actions.handoff_done(outcome, by, left)
        replay(result, for({type, e} <- events, do: {:next_event, type, e}), postponed)
    end
  end

  # The events kept while handing off, after its outcome: the held messages first (inserted
  # events), then the postponed ones (gen_statem takes them again when the state changes).
  # An agent that hands off again at once (its handle_move_failed/4 moved it) stays in
  # :handing_off: the postponed events stay postponed and still count against its bound.
  defp replay({:hand_off, data}, events, postponed),
    do: then_events(transition({:hand_off, %{data | postponed: postponed}}), events)

  defp replay(outcome, events, _postponed), do: then_events(transition(outcome), events)

  defp then_events({:next_state, state, data, actions}, events),
    do: {:next_state, state, data, actions ++ events}

  defp then_events(stop, _events), do: stop

  # The one place where what the agent's code led to (an outcome of Tartarus.Agent.Actions)
  # becomes a state of this machine: runs on in :running, waits for a destination in
  # :handing_off (its deadline armed), or stops.
  defp transition({:run, data, actions}), do: {:next_state, :running, data, actions}

  defp transition({:hand_off, data}) do
    ms = data.host.opts.migration_timeout
    {:next_state, :handing_off, StateTimer.arm(data, :handing_off, ms), []}
  end

  defp transition({:stop, _reason, _data} = stop), do: stop

  defp start_paused(data, paused) do
    data = StateTimer.arm(%{data | paused: paused}, :paused, data.host.opts.migration_timeout)
    {:ok, :paused, data, []}
  end

  # One event of the paused copy.
  defp paused(data, event) do
    case Arrival.step(data, event) do
      # Its state timeout re-armed, or left as it was.
      {:paused, data} ->
        {:keep_state, data}

      {:await, data} ->
        ms = data.host.opts.migration_timeout
        {:next_state, :awaiting_commit, StateTimer.arm(data, :awaiting_commit, ms)}

      {:started, data, pending} ->
        started({:started, StateTimer.cancel(data), pending})

      {:stop, reason, data} ->
        {:stop, reason, StateTimer.cancel(data)}
    end
  end

  # The copy is the agent: the messages that reached it while it moved are handled first
  # (an agent that moves on at every arrival would otherwise carry them for ever), then its
  # handle_arrival/2; if one of them makes it leave, the rest travel on with it.
  defp started({:started, data, []}), do: transition(Actions.arrival(data))

  defp started({:started, data, pending}) do
    {:next_state, :running, data, pending(pending) ++ [{:next_event, :internal, {:arrival, nil}}]}
  end

  defp started({:stop, reason, data}), do: {:stop, reason, data}

  defp pending(msgs), do: Enum.map(msgs, &{:next_event, :internal, {:pending, &1}})

  # Junk in a state it does not leave (Actions.dropped/1 only counts it).
  defp keep_state({:run, data, actions}), do: {:keep_state, data, actions}
end
