defmodule Tartarus.Host.Parked do
  @moduledoc false
  # A host's parked copies (Tartarus.Migration.CopyProtocol.step/2, parked/1): a paused copy
  # that waited too long for its decision hands its record to its host and stops; the host
  # keeps the record (in its ledger and journal), asks the source at a low rate and revives
  # or drops the copy only on an answer. Runs in the host's server, on the server's state.

  alias Tartarus.Ledger
  alias Tartarus.Host.Agents
  alias Tartarus.Migration.{CopyProtocol, Messages}

  # How often a host asks the sources of its parked copies.
  @ask_every 30_000

  @doc false
  # The record of copy `pid` of migration `{mig, copy}`: only the copy itself, found as its
  # agent's arriving process here, may hand it over.
  def park(state, {mig, copy}, env, src, kind, pid) do
    if Ledger.arriving?(state.host, env.id, pid) do
      if Ledger.park(state.host, mig, copy, env, src, kind) and count(state) == 1,
        do: schedule()

      :ok
    else
      {:error, :not_paused_here}
    end
  end

  @doc false
  def count(state), do: Ledger.counter(state.host, :parked)

  @doc false
  # Asks the sources of the parked copies (a timer that only asks: it never decides anything).
  def ask(state) do
    host = state.host

    for {mig, copy, env, src, kind} <- Ledger.parked(host),
        {:ok, pid} <- [Tartarus.Host.whereis(src)] do
      send(pid, Messages.decision_query(mig, Ledger.query_id(env, kind), copy, self()))
    end

    if count(state) > 0, do: schedule()
    :ok
  end

  @doc false
  # A source's answer about a parked copy: revive it (it starts), drop it, or keep it.
  def answer(state, mig, copy, d) do
    case Ledger.fetch_parked(state.host, mig, copy) do
      {:ok, {env, src, kind}} ->
        unpark(state, mig, copy, env, src, kind, d)

      :error ->
        Ledger.count(state.host, :dropped)
        state
    end
  end

  defp schedule, do: Tartarus.Clock.send_after(self(), :"$tartarus_ask_parked", @ask_every)

  defp unpark(state, mig, copy, env, src, kind, d) do
    case CopyProtocol.parked(d) do
      :keep ->
        state

      :drop ->
        Ledger.unpark(state.host, mig, copy)
        Tartarus.Host.Persistence.resolved(state.host, mig, copy)
        state

      :revive ->
        Ledger.unpark(state.host, mig, copy)

        case Agents.start_agent(state, env, {:paused, mig, copy, src, kind, nil}) do
          {:ok, pid, state} ->
            Ledger.put_arriving(state.host, env.id, pid)
            send(pid, Messages.decision(mig, copy, d))
            state

          {:error, _reason, state} ->
            # Kept for the next answer.
            Ledger.park(state.host, mig, copy, env, src, kind)
            state
        end
    end
  end
end
