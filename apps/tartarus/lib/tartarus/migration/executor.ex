defmodule Tartarus.Migration.Executor do
  @moduledoc """
  Carries out the source side of a hand-off: the one place that turns the actions of
  `Tartarus.Migration.Protocol.source_step/2` into effects, in the order the guarantees
  need, through a backend.

  Two backends run this same code: the live one (`Tartarus.Migration.Source`: the host's
  ledger in ETS, its journal, real sends, the agent's mailbox) and the in-memory one of the
  model check (`Tartarus.Migration.ProtocolModelTest`), which may crash the source's host
  between any two effects. So the order below is what the model explores, not a copy of it.

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
end
