defmodule Tartarus.Agent.Server do
  @moduledoc false
  # The process of one agent: a :gen_statem with four states.
  #
  #   * :running: the agent's callbacks run (Tartarus.Agent.Actions carries out what they
  #     return, within their budgets: Tartarus.Agent.Callbacks);
  #   * :handing_off: the source side of a move or clone (Tartarus.Migration.Source) waits
  #     for the destination; what else arrives is kept in data.held (messages for the agent,
  #     calls, anything; bounded in count and bytes, the overflow refused to its senders:
  #     hold/2) and, if the hand-off fails, handled afterwards in its order; if the
  #     move commits, the agent's messages go with the commit (Tartarus.Migration.Inbox) and
  #     the rest is left to its senders' retries. The deadline is a state timeout;
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
  # hand-offs in that time), not gen_statem's own, with gen_statem's semantics: data.timer
  # is {timer, state} for the one armed (state_timeout/3), or nil. Arming one replaces the
  # other; leaving the state it was armed in cancels it (every way out of :handing_off,
  # :paused and :awaiting_commit does: cancel_state_timeout/1); and its message counts only
  # while both are still the same (a stale one, e.g. fired as it was cancelled, is ignored
  # in any state). Per hand-off that is what gen_statem did: one timer armed, one cancelled.
  @behaviour :gen_statem
  require Tartarus.Events

  alias Tartarus.Agent.{Actions, StateTimer}
  alias Tartarus.Ledger
  alias Tartarus.Migration.{Arrival, Inbox, Messages, Source}

  @host :"$tartarus_host"
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
  # The new process's entry point (start/4): becomes a gen_statem. Spawned plainly (not by
  # proc_lib, whose start-up bookkeeping costs more than the rest of an arrival), it names
  # itself as its own parent: gen_statem stops on any {:EXIT, parent, _} message, and anyone
  # can send one; this process stops on its host's signals by the rules of :running.
  def enter(host, key, env, mode) do
    Process.put(:"$ancestors", [self()])
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
    Process.put(@host, host)

    data = %{
      host: host,
      env: env,
      key: key,
      paused: nil,
      inbox: Inbox.new(),
      pending: [],
      handoff: nil,
      held: [],
      # What data.held holds: {count, bytes} (bounded, see hold/2).
      held_size: {0, 0},
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
  defp start(data, {:paused, mig, copy, src, kind, src_pid}) do
    paused = Arrival.paused(data.host, mig, copy, src, kind, src_pid)

    data = StateTimer.arm(%{data | paused: paused}, :paused, data.host.opts.migration_timeout)
    {:ok, :paused, data, []}
  end

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

  def handle_event(:info, {:"$tartarus_msg", {pid, _}, kind, _} = m, :running, data)
      when is_pid(pid) and kind in [:post, :request],
      do: Actions.message(m, data)

  # A message handed over (by the agent's previous process or a late commit): already taken.
  def handle_event(:internal, {:pending, m}, :running, data), do: Actions.handle(m, data)
  def handle_event(:internal, {:init, args}, :running, data), do: Actions.init(data, args)
  def handle_event(:internal, {:arrival, ctx}, :running, data), do: Actions.arrival(data, ctx)

  # Its host kills it (see the top of this module): an agent that traps exits stops too. The
  # mark in the host's ledger tells the host's signal from a forged message. The host's
  # server may have been restarted since this process started: the current one counts.
  def handle_event(:info, {:EXIT, pid, :shutdown} = msg, :running, data)
      when pid == data.host.pid or node(pid) == node() do
    if (pid == data.host.pid or pid == Tartarus.Host.server(data.host)) and
         Ledger.kill_marked?(data.host, self()),
       do: {:stop, :shutdown, data},
       else: Actions.info(msg, data)
  end

  # A commit (with its hand-over) that came after this process stopped waiting for it (its
  # source was slow): what this process took meanwhile is not taken twice.
  def handle_event(:info, {:"$tartarus_commit", _mig, _copy, _notify, {msgs, _}}, :running, data)
      when is_list(msgs) do
    {msgs, inbox} = Inbox.take_new(data.inbox, msgs)
    {:keep_state, %{data | inbox: inbox}, pending(msgs)}
  end

  # Malformed messages for the agent, late replies of hand-offs it gave up on, commits or
  # answers delivered twice: not for the agent's code.
  def handle_event(:info, msg, :running, data)
      when is_tuple(msg) and elem(msg, 0) == :"$tartarus_msg",
      do: Actions.dropped(data)

  def handle_event(:info, msg, :running, data) do
    if Messages.protocol_message?(msg), do: :keep_state_and_data, else: Actions.info(msg, data)
  end

  def handle_event({:call, from}, _op, _state, data) when not Tartarus.Events.is_from(from),
    do: Actions.dropped(data) |> keep_state()

  def handle_event({:call, from}, op, :running, data), do: Actions.call(op, from, data)
  def handle_event(:cast, _msg, :running, data), do: Actions.dropped(data)

  # -- :handing_off --------------------------------------------------------------------
  # Tartarus.Migration.Source reads the destination's answers; everything else waits in
  # data.held (see the top of this module).

  def handle_event(:info, msg, :handing_off, data) do
    case Source.event(data, msg) do
      nil -> hold(data, {:info, msg})
      event -> handoff(data, event)
    end
  end

  # The rest of a hand-over being handled when the agent left again: still taken, not handled.
  def handle_event(:internal, {:pending, m}, :handing_off, data),
    do: {:keep_state, %{data | pending: data.pending ++ [m]}}

  def handle_event(type, content, :handing_off, data), do: hold(data, {type, content})

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
    if Process.get(:"$tartarus_children"), do: Tartarus.Agent.end_children(data.host, self())

    unless reason in [:normal, :shutdown] or match?({:shutdown, _}, reason),
      do: Ledger.put_exit_reason(data.host, self(), reason)
  end

  # -- helpers ---------------------------------------------------------------------------

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
        data = StateTimer.cancel(data)
        held = for {type, content} <- Enum.reverse(data.held), do: {:next_event, type, content}

        result =
          Actions.handoff_done(outcome, by, %{data | pending: [], held: [], held_size: {0, 0}})

        replay(result, pending(data.pending) ++ held)
    end
  end

  # What a handing-off agent keeps for later is bounded: at most the host option :max_held
  # events and :max_held_bytes bytes (external size: binaries count whole, wherever they
  # live). Beyond that, a message for the agent is refused to its sender (post and request
  # return {:error, {:overloaded, id}}), a call answered the same, anything else dropped
  # and counted: the agent is never killed for what others send it.
  defp hold(data, event) do
    {n, bytes} = data.held_size
    size = held_bytes(event)
    opts = data.host.opts

    if n < Map.get(opts, :max_held, 1_000) and
         bytes + size <= Map.get(opts, :max_held_bytes, 8_388_608) do
      {:keep_state, %{data | held: [event | data.held], held_size: {n + 1, bytes + size}}}
    else
      overflow(data, event)
    end
  end

  defp held_bytes({:info, {:"$tartarus_msg", _from, _kind, msg}}), do: :erlang.external_size(msg)
  defp held_bytes({_type, content}), do: :erlang.external_size(content)

  defp overflow(data, {:info, {:"$tartarus_msg", {pid, ref}, _kind, _msg}}) when is_pid(pid) do
    send(pid, {ref, {:failed, {:overloaded, data.env.id}}})
    Ledger.count(data.host, :dropped)
    :keep_state_and_data
  end

  defp overflow(data, {{:call, from}, _request}) do
    Tartarus.Events.reply(from, {:error, {:overloaded, data.env.id}})
    Ledger.count(data.host, :dropped)
    :keep_state_and_data
  end

  defp overflow(data, _event) do
    Ledger.count(data.host, :dropped)
    :keep_state_and_data
  end

  defp replay({:next_state, state, data, actions}, events),
    do: {:next_state, state, data, actions ++ events}

  defp replay(stop, _events), do: stop

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
  defp started({:started, data, []}), do: Actions.arrival(data)

  defp started({:started, data, pending}) do
    {:next_state, :running, data, pending(pending) ++ [{:next_event, :internal, {:arrival, nil}}]}
  end

  defp started({:stop, reason, data}), do: {:stop, reason, data}

  defp pending(msgs), do: Enum.map(msgs, &{:next_event, :internal, {:pending, &1}})

  defp keep_state({:next_state, _state, data, actions}), do: {:keep_state, data, actions}
end
