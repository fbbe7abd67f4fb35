defmodule Tartarus.Migration.Executor do
  @moduledoc """
  Carries out the hand-off: the one place that turns the actions of
  `Tartarus.Migration.Protocol` into effects, in the order the guarantees need, through a
  backend, for its three roles: the source (`source_event/4`), the destination host's
  admission (`destination_event/4`) and the paused copy (`copy_event/4`).

  Two backends run this same code: the live ones (`Tartarus.Migration.Source`: the host's
  ledger in ETS, its journal, real sends, the agent's mailbox; `Tartarus.Host.Arrivals`:
  admission checks, spawning the copy, its journal record; `Tartarus.Migration.Arrival`:
  asking, stashing, parking, starting) and the in-memory one of the model check
  (`apps/tartarus/test/tartarus/migration/protocol_model.exs`), which may crash the source's
  host between any two of its effects. So the order below is what the model explores, not a
  copy of it.

  ## Effects, in order

  A **move** that commits:

    1. `journal({:decision, mig, id, copy})`, then `journal({:forget, id})`: durable before
       anything else (a restarted host must neither lose the commit nor restore the agent);
    2. `pointer_put(mig, copy, notify)`: the forwarding pointer replaces the hand-off
       record in one write; it is the decision a destination in doubt reads;
    3. `leave()`: the agent is no longer resident here;
    4. `handover()` then `send(copy_pid, commit)`: the commit carries the messages the
       source took and had not handled (`Tartarus.Migration.Inbox`).

  A **clone** that commits: `decision_put_new(mig, copy)` (insert-if-absent), then
  `journal({:decision, mig, clone_id, copy})`, then `handoff_end(mig)` and `send(commit)`.

  An **abort**: `handoff_end(mig)` and nothing else (an abort is the absence of a commit
  once the hand-off record is gone).

  Before the decision (or the abort) the backend hears `settled/2`: the live backend stops
  watching the destination there.

  An **admission** (`destination_event/4`): the checks (`check/2`: trust, size, code,
  capacity, policy; a copy token), or `probe/4` for a prepare seen before; then
  `create/3` (the paused copy), `journal({:in_doubt, ...})` (durable before the answer) and
  `send(prepared)`; or `send(need)`, or `refuse/3`.

  A **paused copy** (`copy_event/4`): `copy_state/2` (its new protocol state), then
  `ask/3`, `timer/2`, `stash/2`, `drop/2` in order, and at most one of `start/3`, `abort/2`,
  `park/2`, which end it: their result is returned as `{:done, result}`.

  A backend effect may `throw({:halt, ctx})` (the model's crash of the source's host):
  the effects after it do not happen and `source/4` returns `{:halted, ctx}`.
  """

  alias Tartarus.Migration.{Messages, Protocol}

  @typedoc "The backend's context, threaded through every effect."
  @type ctx :: term()

  @callback settled(ctx, {:prepared, pid() | term()} | :failed) :: ctx
  @callback decision_put_new(ctx, Protocol.mig(), Protocol.copy_token()) :: {boolean(), ctx}
  @callback journal(ctx, tuple()) :: ctx
  @callback pointer_put(ctx, Protocol.mig(), Protocol.copy_token(), term()) :: ctx
  @callback leave(ctx) :: ctx
  @callback handoff_end(ctx, Protocol.mig()) :: ctx
  @callback handover(ctx) :: {term(), ctx}
  @callback send(ctx, term(), term()) :: ctx
  @callback fetch_code(ctx, [module()]) :: {{:ok, list()} | {:error, term()}, ctx}
  @callback resend(ctx, list()) :: ctx
  @callback committed(ctx, :move | :clone, Protocol.mig(), Protocol.copy_token()) :: ctx

  # The destination's admission.
  @callback check(ctx, map()) :: {:ok | {:need, list()} | {:error, term()}, term(), ctx}
  @callback probe(ctx, map(), Protocol.copy_token(), term()) :: {boolean(), ctx}
  @callback create(ctx, map(), Protocol.copy_token()) :: {{:ok, term()} | {:error, term()}, ctx}
  @callback refuse(ctx, map(), term()) :: ctx

  # The paused copy.
  @callback copy_state(ctx, map()) :: ctx
  @callback ask(ctx, term(), Protocol.mig(), Protocol.copy_token()) :: ctx
  @callback timer(ctx, non_neg_integer()) :: ctx
  @callback stash(ctx, term()) :: ctx
  @callback drop(ctx, term()) :: ctx
  @callback start(ctx, map(), term()) :: term()
  @callback abort(ctx, map()) :: term()
  @callback park(ctx, map()) :: term()

  # Each live backend serves one role.
  @optional_callbacks settled: 2,
                      decision_put_new: 3,
                      journal: 2,
                      pointer_put: 4,
                      leave: 1,
                      handoff_end: 2,
                      handover: 1,
                      send: 3,
                      fetch_code: 2,
                      resend: 2,
                      committed: 4,
                      check: 2,
                      probe: 4,
                      create: 3,
                      refuse: 3,
                      copy_state: 2,
                      ask: 4,
                      timer: 2,
                      stash: 2,
                      drop: 2,
                      start: 3,
                      abort: 2,
                      park: 2

  @doc """
  The source's state for one attempt: `Tartarus.Migration.Protocol.source/4` with the
  agent's id and the id of what leaves (the agent's for a move, the clone's for a clone).
  """
  @spec source_state(Protocol.mig(), :move | :clone, term(), term(), binary(), binary()) ::
          map()
  def source_state(mig, kind, dest, notify, agent, out) do
    mig |> Protocol.source(kind, dest, notify) |> Map.merge(%{agent: agent, out: out})
  end

  @doc """
  Feeds `event` to the source's state machine and carries out its actions. Returns
  `{:wait, s, ctx}` (wait for the next event), `{:done, outcome, s, ctx}` or
  `{:halted, ctx}`.
  """
  @spec source_event(map(), term(), ctx, module()) ::
          {:wait, map(), ctx} | {:done, term(), map(), ctx} | {:halted, ctx}
  def source_event(s, event, ctx, backend) do
    {s, actions} = Protocol.source_step(s, event)
    source(s, actions, ctx, backend)
  end

  @doc "Carries out `actions` of the source's state `s` (see `source_event/4`)."
  @spec source(map(), list(), ctx, module()) ::
          {:wait, map(), ctx} | {:done, term(), map(), ctx} | {:halted, ctx}
  def source(s, actions, ctx, backend) do
    run(s, actions, ctx, backend)
  catch
    {:halt, ctx} -> {:halted, ctx}
  end

  defp run(s, [], ctx, _b), do: {:wait, s, ctx}

  defp run(s, [{:decide, mig, {:committed, copy}} | rest], ctx, b) do
    {:deciding, _, pid} = s.phase
    ctx = b.settled(ctx, {:prepared, pid})

    # A move's decision is its forwarding pointer, written with the commit's record below.
    {ok, ctx} = if s.kind == :move, do: {true, ctx}, else: b.decision_put_new(ctx, mig, copy)
    {s, more} = Protocol.source_step(s, {:decided, ok})
    run(s, more ++ rest, ctx, b)
  end

  defp run(s, [{:record_commit, :move, mig, copy} | rest], ctx, b) do
    ctx =
      ctx
      |> b.journal({:decision, mig, s.agent, copy})
      |> b.journal({:forget, s.agent})
      |> b.pointer_put(mig, copy, s.notify)
      |> b.leave()
      |> b.committed(:move, mig, copy)

    run(s, rest, ctx, b)
  end

  defp run(s, [{:record_commit, :clone, mig, copy} | rest], ctx, b) do
    ctx = ctx |> b.journal({:decision, mig, s.out, copy}) |> b.committed(:clone, mig, copy)
    run(s, rest, ctx, b)
  end

  defp run(s, [{:end_handoff, mig} | rest], ctx, b) do
    ctx =
      case s.phase do
        # Replaced by the forwarding pointer already.
        {:committed, _, _} when s.kind == :move -> ctx
        {:committed, _, _} -> b.handoff_end(ctx, mig)
        _failed -> ctx |> b.settled(:failed) |> b.handoff_end(mig)
      end

    run(s, rest, ctx, b)
  end

  defp run(s, [{:send, to, {:"$tartarus_commit", mig, copy, notify, _}} | rest], ctx, b) do
    {handover, ctx} = if s.kind == :move, do: b.handover(ctx), else: {nil, ctx}
    run(s, rest, b.send(ctx, to, Messages.commit(mig, copy, notify, handover)), b)
  end

  defp run(s, [{:send, to, msg} | rest], ctx, b), do: run(s, rest, b.send(ctx, to, msg), b)

  defp run(s, [{:fetch_code, mods} | rest], ctx, b) do
    {result, ctx} = b.fetch_code(ctx, mods)
    {s, more} = Protocol.source_step(s, {:code, result})
    run(s, more ++ rest, ctx, b)
  end

  defp run(s, [{:resend, code} | rest], ctx, b), do: run(s, rest, b.resend(ctx, code), b)

  defp run(s, [{:done, outcome} | _], ctx, _b), do: {:done, outcome, s, ctx}

  # -- the destination's admission ---------------------------------------------------------

  @doc """
  Feeds `event` to the destination's state `d` (`Protocol.destination_step/2`) and carries
  out its actions, feeding back what the checks, probes and creates found. Returns
  `{d, ctx}`.
  """
  @spec destination_event(map(), term(), ctx, module()) :: {map(), ctx}
  def destination_event(d, event, ctx, b) do
    {d, actions} = Protocol.destination_step(d, event)
    Enum.reduce(actions, {d, ctx}, fn action, {d, ctx} -> destination(action, d, ctx, b) end)
  end

  defp destination({:check, p}, d, ctx, b) do
    {verdict, copy, ctx} = b.check(ctx, p)
    destination_event(d, {:checked, p, verdict, copy}, ctx, b)
  end

  defp destination({:probe, p, copy, pid}, d, ctx, b) do
    {paused?, ctx} = b.probe(ctx, p, copy, pid)
    destination_event(d, {:probed, p, copy, pid, paused?}, ctx, b)
  end

  defp destination({:create, p, copy}, d, ctx, b) do
    case b.create(ctx, p, copy) do
      {{:ok, pid}, ctx} -> destination_event(d, {:created, p, copy, pid}, ctx, b)
      {{:error, reason}, ctx} -> destination_event(d, {:create_failed, p, reason}, ctx, b)
    end
  end

  # Durable before `prepared` leaves (the next action).
  defp destination({:journal_in_doubt, p, copy}, d, ctx, b),
    do: {d, b.journal(ctx, {:in_doubt, p.mig, p.env, p.src, p.kind, copy})}

  defp destination({:send, to, msg}, d, ctx, b), do: {d, b.send(ctx, to, msg)}
  defp destination({:refuse, p, reason}, d, ctx, b), do: {d, b.refuse(ctx, p, reason)}

  # -- the paused copy -------------------------------------------------------------------

  @doc """
  Feeds `event` to the paused copy's state `c` (`Protocol.copy_step/2`) and carries out its
  actions. Returns `{:paused, ctx}` (it waits on) or `{:done, result}` (what the backend's
  `start/3`, `abort/2` or `park/2` returned).
  """
  @spec copy_event(map(), term(), ctx, module()) :: {:paused, ctx} | {:done, term()}
  def copy_event(c, event, ctx, b) do
    {c, actions} = Protocol.copy_step(c, event)
    copy(actions, c, b.copy_state(ctx, c), b)
  end

  defp copy([], _c, ctx, _b), do: {:paused, ctx}
  defp copy([{:start, notify} | _], c, ctx, b), do: {:done, b.start(ctx, c, notify)}
  defp copy([:abort | _], c, ctx, b), do: {:done, b.abort(ctx, c)}
  defp copy([:park | _], c, ctx, b), do: {:done, b.park(ctx, c)}

  defp copy([{:ask, src, mig, copy} | rest], c, ctx, b),
    do: copy(rest, c, b.ask(ctx, src, mig, copy), b)

  defp copy([{:timer, ms} | rest], c, ctx, b), do: copy(rest, c, b.timer(ctx, ms), b)
  defp copy([{:stash, msg} | rest], c, ctx, b), do: copy(rest, c, b.stash(ctx, msg), b)
  defp copy([{:drop, msg} | rest], c, ctx, b), do: copy(rest, c, b.drop(ctx, msg), b)
end
