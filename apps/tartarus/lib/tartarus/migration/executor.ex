defmodule Tartarus.Migration.Executor do
  @moduledoc """
  Carries out the hand-off: a flat loop that feeds an event to one role's state machine of
  `Tartarus.Migration.Protocol`, carries out the actions it returns one by one, each through
  the callback of the same name of the role's backend, and feeds what an action found back
  as the next event (as Livebook's `Session.Data` does): the protocol is never re-entered
  from inside an action. The executor decides nothing: which effects happen, in which order,
  is the protocol's alone.

  Four roles, one behaviour each, every callback required (the compiler checks a backend):
  `Tartarus.Migration.Executor.Source` (the source, `source_event/4`),
  `Tartarus.Migration.Executor.Destination` (the destination host's admission,
  `destination_event/4`), `Tartarus.Migration.Executor.Copy` (the paused copy,
  `Tartarus.Migration.CopyProtocol`, `copy_event/4`) and `Tartarus.Migration.Executor.Host`
  (a host's own part, `Tartarus.Migration.HostProtocol`: answers, acknowledgements, parked
  copies, `host_event/3`). The live backends are `Tartarus.Migration.Source`,
  `Tartarus.Host.Arrivals`, `Tartarus.Migration.Arrival` and `Tartarus.Host.Parked`; the
  model check (`apps/tartarus/test/tartarus/migration/protocol_model.exs`) is the other
  backend of all four, and may crash a host between any two effects of any role: the order
  is what the model explores, not a copy of it.

  Actions with a result, and the event it comes back as: source `{:decide, mig, copy}` ->
  `{:decided, boolean}`, `{:fetch_code, mods}` -> `{:code, result}`; destination
  `{:check, p}` -> `{:checked, p, verdict, copy}`, `{:probe, p, copy, pid}` ->
  `{:probed, p, copy, pid, boolean}`, `{:create, p, copy}` -> `{:created, p, copy, pid}` or
  `{:create_failed, p, reason}`; copy `:register` -> `{:registered, result}`, `{:claim, mig, copy}` -> `{:claimed, taken?}`. A source's
  `{:done, outcome}` and a copy's `:started`, `{:await, pid}`, `{:stop, reason}` and `:park`
  end the loop.

  A backend effect may `throw({:halt, ctx})` (the model's crash of a host): the effects
  after it do not happen and `source_event/4` and `copy_event/4` return `{:halted, ctx}`
  (`destination_event/4` and `host_event/3` let it through to the caller).
  """

  alias Tartarus.Migration.{CopyProtocol, HostProtocol, Protocol}

  @typedoc "The backend's context, threaded through every effect."
  @type ctx :: term()

  defmodule Source do
    @moduledoc "The source's effects (`Tartarus.Migration.Protocol.source_step/2`'s actions)."
    alias Tartarus.Migration.Protocol
    @type ctx :: term()

    @doc "The hand-off record of `mig`, before `prepare` leaves."
    @callback begin_handoff(ctx, Protocol.mig()) :: ctx
    @doc "Watch the destination."
    @callback watch(ctx) :: ctx
    @doc "Send the prepare."
    @callback send_prepare(ctx) :: ctx
    @doc "Stop watching the destination (it answered, or the attempt failed)."
    @callback settle(ctx, {:prepared, term()} | :failed) :: ctx
    @doc "A clone's commit, insert-if-absent."
    @callback decide(ctx, Protocol.mig(), Protocol.copy_token()) :: {boolean(), ctx}
    @doc "A journal record."
    @callback journal(ctx, tuple()) :: ctx
    @doc "A move's forwarding pointer (it replaces the hand-off record)."
    @callback pointer_put(ctx, Protocol.mig(), Protocol.copy_token(), term()) :: ctx
    @doc "The agent leaves the resident tables."
    @callback leave(ctx) :: ctx
    @doc "The commit's event."
    @callback committed(ctx, :move | :clone, Protocol.mig(), Protocol.copy_token()) :: ctx
    @doc "The hand-off record goes."
    @callback end_handoff(ctx, Protocol.mig()) :: ctx
    @doc "A move's commit, sent with the hand-over of the agent's messages."
    @callback hand_over(ctx, term(), tuple()) :: ctx
    @doc "A message."
    @callback send(ctx, term(), term()) :: ctx
    @doc "The code of `mods`."
    @callback fetch_code(ctx, [module()]) :: {{:ok, list()} | {:error, term()}, ctx}
    @doc "The prepare again, with code."
    @callback resend(ctx, list()) :: ctx
  end

  defmodule Destination do
    @moduledoc "Admission's effects (`Tartarus.Migration.Protocol.destination_step/2`'s actions)."
    alias Tartarus.Migration.Protocol
    @type ctx :: term()

    @doc "Trust, size, code, capacity, policy; a fresh copy token."
    @callback check(ctx, map()) :: {:ok | {:need, list()} | {:error, term()}, term(), ctx}
    @doc "Is that copy still paused?"
    @callback probe(ctx, map(), Protocol.copy_token(), term()) :: {boolean(), ctx}
    @doc "The paused copy."
    @callback create(ctx, map(), Protocol.copy_token()) :: {{:ok, term()} | {:error, term()}, ctx}
    @doc "The in-doubt copy's journal record."
    @callback journal_in_doubt(ctx, tuple()) :: ctx
    @doc "An answer to the source."
    @callback answer(ctx, term(), term()) :: ctx
    @doc "A refusal (nothing was created)."
    @callback refuse(ctx, map(), term()) :: ctx
  end

  defmodule Copy do
    @moduledoc "The paused copy's effects (`Tartarus.Migration.CopyProtocol.step/2`'s actions)."
    alias Tartarus.Migration.Protocol
    @type ctx :: term()

    @doc "Its new protocol state (before its actions)."
    @callback copy_state(ctx, map()) :: ctx
    @doc "Ask the source host."
    @callback ask(ctx, term(), Protocol.mig(), Protocol.copy_token()) :: ctx
    @doc "Re-arm its timer."
    @callback timer(ctx, non_neg_integer()) :: ctx
    @doc "Keep a message for later."
    @callback stash(ctx, term()) :: ctx
    @doc "Drop a message (over the bound)."
    @callback drop(ctx, term()) :: ctx
    @doc "Its own state as the agent's: the hand-over and the stash taken, the hop counted."
    @callback become(ctx, term()) :: ctx
    @doc "Resident here."
    @callback register(ctx) :: {:ok | {:error, term()}, ctx}
    @doc "A revived copy takes its parked record: true if it was there."
    @callback claim(ctx, Protocol.mig(), Protocol.copy_token()) :: {boolean(), ctx}
    @doc "The snapshot a crash restarts from."
    @callback put_snapshot(ctx) :: ctx
    @doc "The journal's record of the agent."
    @callback checkpoint(ctx) :: ctx
    @doc "No longer findable as arriving."
    @callback drop_arriving(ctx) :: ctx
    @doc "The journal's in-doubt record ends."
    @callback resolve(ctx, Protocol.mig(), Protocol.copy_token()) :: ctx
    @doc "The acknowledgement to the source host."
    @callback ack(ctx, term(), Protocol.mig(), Protocol.copy_token()) :: ctx
    @doc "The arrival's event and hop time."
    @callback arrived(ctx) :: ctx
    @doc "The answer to whoever waits for the move."
    @callback reply(ctx, term(), :move | :clone) :: ctx
    @doc "Ends the loop: it runs as the agent."
    @callback started(ctx, map()) :: term()
    @doc "Ends the loop: it waits for its source's commit."
    @callback await(ctx, pid() | term()) :: term()
    @doc "Ends the loop: it stops with `reason`."
    @callback stop(ctx, term()) :: term()
    @doc "Ends the loop: the record goes to the host, the process stops."
    @callback park(ctx, map()) :: term()
  end

  defmodule Host do
    @moduledoc "A host's own effects (`Tartarus.Migration.HostProtocol.step/1`'s actions)."
    @type ctx :: term()

    @doc "The ledger's view of `mig` for `Tartarus.Migration.Protocol.answer/3`."
    @callback read(ctx, term(), binary(), term()) :: {map(), ctx}
    @doc "A message."
    @callback tell(ctx, term(), term()) :: ctx
    @doc "The commit is no longer needed."
    @callback acknowledge(ctx, term(), binary(), term()) :: ctx
    @doc "A journal record."
    @callback record(ctx, tuple()) :: ctx
    @doc "A parked copy's record, if the caller is that copy: `:first`, `:more`, `:not_here`."
    @callback park(ctx, term(), term(), map(), term(), atom(), term()) ::
                {:first | :more | :not_here, ctx}
    @doc "The answer to a call."
    @callback reply_call(ctx, term(), term()) :: ctx
    @doc "The timer that asks for the parked copies."
    @callback arm_ask(ctx) :: ctx
    @doc "The parked records, `{mig, copy, env, src, kind}`."
    @callback read_parked(ctx) :: {list(), ctx}
    @doc "A decision query to a source host, `{mig, id, copy}`."
    @callback ask(ctx, term(), tuple()) :: ctx
    @doc "A parked record."
    @callback fetch_parked(ctx, term(), term()) :: {{:ok, tuple()} | :error, ctx}
    @doc "Counted as dropped."
    @callback dropped(ctx) :: ctx
    @doc "The parked record goes."
    @callback unpark(ctx, term(), term()) :: ctx
    @doc "A paused copy again, from a parked record (which it takes itself as it starts)."
    @callback revive(ctx, term(), term(), map(), term(), atom()) :: {{:ok, term()} | :error, ctx}
    @doc "The agent's arriving process."
    @callback arriving(ctx, binary(), term()) :: ctx
  end

  # -- the source --------------------------------------------------------------------------

  @doc """
  Feeds `event` to the source's state machine and carries out its actions. Returns
  `{:wait, s, ctx}` (wait for the next event), `{:done, outcome, s, ctx}` or
  `{:halted, ctx}`.
  """
  @spec source_event(map(), term(), ctx, module()) ::
          {:wait, map(), ctx} | {:done, term(), map(), ctx} | {:halted, ctx}
  def source_event(s, event, ctx, b) do
    source_loop(s, [event], ctx, b)
  catch
    {:halt, ctx} -> {:halted, ctx}
  end

  defp source_loop(s, [], ctx, _b), do: {:wait, s, ctx}

  defp source_loop(s, [event | events], ctx, b) do
    {s, actions} = Protocol.source_step(s, event)

    case source(actions, ctx, b, events) do
      {:next, ctx, events} -> source_loop(s, events, ctx, b)
      {:done, outcome, ctx} -> {:done, outcome, s, ctx}
    end
  end

  defp source([], ctx, _b, events), do: {:next, ctx, events}
  defp source([{:done, outcome} | _], ctx, _b, _events), do: {:done, outcome, ctx}

  defp source([{:decide, mig, copy} | rest], ctx, b, events) do
    {ok, ctx} = b.decide(ctx, mig, copy)
    source(rest, ctx, b, events ++ [{:decided, ok}])
  end

  defp source([{:fetch_code, mods} | rest], ctx, b, events) do
    {result, ctx} = b.fetch_code(ctx, mods)
    source(rest, ctx, b, events ++ [{:code, result}])
  end

  defp source([action | rest], ctx, b, events),
    do: source(rest, effect(action, ctx, b), b, events)

  defp effect({:begin_handoff, mig}, ctx, b), do: b.begin_handoff(ctx, mig)
  defp effect(:watch, ctx, b), do: b.watch(ctx)
  defp effect(:send_prepare, ctx, b), do: b.send_prepare(ctx)
  defp effect({:settle, how}, ctx, b), do: b.settle(ctx, how)
  defp effect({:journal, record}, ctx, b), do: b.journal(ctx, record)

  defp effect({:pointer_put, mig, copy, notify}, ctx, b),
    do: b.pointer_put(ctx, mig, copy, notify)

  defp effect(:leave, ctx, b), do: b.leave(ctx)
  defp effect({:committed, kind, mig, copy}, ctx, b), do: b.committed(ctx, kind, mig, copy)
  defp effect({:end_handoff, mig}, ctx, b), do: b.end_handoff(ctx, mig)
  defp effect({:hand_over, to, commit}, ctx, b), do: b.hand_over(ctx, to, commit)
  defp effect({:send, to, msg}, ctx, b), do: b.send(ctx, to, msg)
  defp effect({:resend, code}, ctx, b), do: b.resend(ctx, code)

  # -- the destination's admission ---------------------------------------------------------

  @doc """
  Feeds `event` to the destination's state `d` (`Protocol.destination_step/2`) and carries
  out its actions; what a check, probe or create found is the next event. Returns
  `{d, ctx}`.
  """
  @spec destination_event(map(), term(), ctx, module()) :: {map(), ctx}
  def destination_event(d, event, ctx, b), do: destination_loop(d, [event], ctx, b)

  defp destination_loop(d, [], ctx, _b), do: {d, ctx}

  defp destination_loop(d, [event | events], ctx, b) do
    {d, actions} = Protocol.destination_step(d, event)
    {ctx, events} = destination(actions, ctx, b, events)
    destination_loop(d, events, ctx, b)
  end

  defp destination([], ctx, _b, events), do: {ctx, events}

  defp destination([{:check, p} | rest], ctx, b, events) do
    {verdict, copy, ctx} = b.check(ctx, p)
    destination(rest, ctx, b, events ++ [{:checked, p, verdict, copy}])
  end

  defp destination([{:probe, p, copy, pid} | rest], ctx, b, events) do
    {paused?, ctx} = b.probe(ctx, p, copy, pid)
    destination(rest, ctx, b, events ++ [{:probed, p, copy, pid, paused?}])
  end

  defp destination([{:create, p, copy} | rest], ctx, b, events) do
    {event, ctx} =
      case b.create(ctx, p, copy) do
        {{:ok, pid}, ctx} -> {{:created, p, copy, pid}, ctx}
        {{:error, reason}, ctx} -> {{:create_failed, p, reason}, ctx}
      end

    destination(rest, ctx, b, events ++ [event])
  end

  defp destination([{:journal, record} | rest], ctx, b, events),
    do: destination(rest, b.journal_in_doubt(ctx, record), b, events)

  defp destination([{:send, to, msg} | rest], ctx, b, events),
    do: destination(rest, b.answer(ctx, to, msg), b, events)

  defp destination([{:refuse, p, reason} | rest], ctx, b, events),
    do: destination(rest, b.refuse(ctx, p, reason), b, events)

  # -- the paused copy -------------------------------------------------------------------

  @doc """
  Feeds `event` to the paused copy's state `c` (`CopyProtocol.step/2`) and carries out its
  actions; what `:register` found is the next event. Returns `{:paused, ctx}` (it waits on),
  `{:done, result}` (what the backend's `started/2`, `await/2`, `stop/2` or `park/2`
  returned) or `{:halted, ctx}`.
  """
  @spec copy_event(map(), term(), ctx, module()) ::
          {:paused, ctx} | {:done, term()} | {:halted, ctx}
  def copy_event(c, event, ctx, b) do
    copy_loop(c, [event], ctx, b)
  catch
    {:halt, ctx} -> {:halted, ctx}
  end

  defp copy_loop(_c, [], ctx, _b), do: {:paused, ctx}

  defp copy_loop(c, [event | events], ctx, b) do
    {c, actions} = CopyProtocol.step(c, event)

    case copy(actions, c, b.copy_state(ctx, c), b, events) do
      {:next, ctx, events} -> copy_loop(c, events, ctx, b)
      done -> done
    end
  end

  defp copy([], _c, ctx, _b, events), do: {:next, ctx, events}
  defp copy([:started | _], c, ctx, b, _), do: {:done, b.started(ctx, c)}
  defp copy([{:await, pid} | _], _c, ctx, b, _), do: {:done, b.await(ctx, pid)}
  defp copy([{:stop, reason} | _], _c, ctx, b, _), do: {:done, b.stop(ctx, reason)}
  defp copy([:park | _], c, ctx, b, _), do: {:done, b.park(ctx, c)}

  defp copy([{:claim, mig, copy} | rest], c, ctx, b, events) do
    {taken, ctx} = b.claim(ctx, mig, copy)
    copy(rest, c, ctx, b, events ++ [{:claimed, taken}])
  end

  defp copy([:register | rest], c, ctx, b, events) do
    {result, ctx} = b.register(ctx)
    copy(rest, c, ctx, b, events ++ [{:registered, result}])
  end

  defp copy([action | rest], c, ctx, b, events),
    do: copy(rest, c, copy_effect(action, ctx, b), b, events)

  defp copy_effect({:ask, src, mig, copy}, ctx, b), do: b.ask(ctx, src, mig, copy)
  defp copy_effect({:timer, ms}, ctx, b), do: b.timer(ctx, ms)
  defp copy_effect({:stash, msg}, ctx, b), do: b.stash(ctx, msg)
  defp copy_effect({:drop, msg}, ctx, b), do: b.drop(ctx, msg)
  defp copy_effect({:become, handover}, ctx, b), do: b.become(ctx, handover)
  defp copy_effect(:put_snapshot, ctx, b), do: b.put_snapshot(ctx)
  defp copy_effect(:checkpoint, ctx, b), do: b.checkpoint(ctx)
  defp copy_effect(:drop_arriving, ctx, b), do: b.drop_arriving(ctx)
  defp copy_effect({:resolve, mig, copy}, ctx, b), do: b.resolve(ctx, mig, copy)
  defp copy_effect({:ack, src, mig, copy}, ctx, b), do: b.ack(ctx, src, mig, copy)
  defp copy_effect(:arrived, ctx, b), do: b.arrived(ctx)
  defp copy_effect({:reply, notify, kind}, ctx, b), do: b.reply(ctx, notify, kind)

  # -- a host's own part ----------------------------------------------------------------

  @doc """
  Carries out a host's actions for `event` (`HostProtocol.step/1`); what a read, park,
  fetch or revive found is the next event. Returns `ctx`.
  """
  @spec host_event(term(), ctx, module()) :: ctx
  def host_event(event, ctx, b), do: host_loop([event], ctx, b)

  defp host_loop([], ctx, _b), do: ctx

  defp host_loop([event | events], ctx, b) do
    {ctx, events} = host(HostProtocol.step(event), ctx, b, events)
    host_loop(events, ctx, b)
  end

  defp host([], ctx, _b, events), do: {ctx, events}

  defp host([{:read, mig, id, copy, to} | rest], ctx, b, events) do
    {view, ctx} = b.read(ctx, mig, id, copy)
    host(rest, ctx, b, events ++ [{:read, mig, copy, to, view}])
  end

  defp host([{:park, mig, copy, env, src, kind, from} | rest], ctx, b, events) do
    {how, ctx} = b.park(ctx, mig, copy, env, src, kind, from)
    host(rest, ctx, b, events ++ [{:parked, from, how}])
  end

  defp host([:read_parked | rest], ctx, b, events) do
    {records, ctx} = b.read_parked(ctx)
    host(rest, ctx, b, events ++ [{:asking, records}])
  end

  defp host([{:fetch_parked, mig, copy, d} | rest], ctx, b, events) do
    {found, ctx} = b.fetch_parked(ctx, mig, copy)
    host(rest, ctx, b, events ++ [{:fetched, mig, copy, d, found}])
  end

  defp host([{:revive, mig, copy, d, env, src, kind} | rest], ctx, b, events) do
    {result, ctx} = b.revive(ctx, mig, copy, env, src, kind)
    host(rest, ctx, b, events ++ [{:revived, mig, copy, d, result, env, src, kind}])
  end

  defp host([action | rest], ctx, b, events),
    do: host(rest, host_effect(action, ctx, b), b, events)

  defp host_effect({:send, to, msg}, ctx, b), do: b.tell(ctx, to, msg)
  defp host_effect({:acknowledge, mig, id, copy}, ctx, b), do: b.acknowledge(ctx, mig, id, copy)
  defp host_effect({:journal, record}, ctx, b), do: b.record(ctx, record)
  defp host_effect({:reply, from, answer}, ctx, b), do: b.reply_call(ctx, from, answer)
  defp host_effect(:arm_ask, ctx, b), do: b.arm_ask(ctx)
  defp host_effect({:ask, src, query}, ctx, b), do: b.ask(ctx, src, query)
  defp host_effect(:dropped, ctx, b), do: b.dropped(ctx)
  defp host_effect({:unpark, mig, copy}, ctx, b), do: b.unpark(ctx, mig, copy)
  defp host_effect({:arriving, id, pid}, ctx, b), do: b.arriving(ctx, id, pid)
end
