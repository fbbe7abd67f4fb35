defmodule Tartarus.Host.Parked do
  @moduledoc false
  # A host's parked copies (Tartarus.Migration.CopyProtocol.step/2, parked/1): a paused copy
  # that waited too long for its decision hands its record to its host and stops; the host
  # keeps the record (in its ledger and journal), asks the source at a low rate and revives
  # or drops the copy only on an answer (Tartarus.Migration.HostProtocol decides; this module
  # carries out its actions, as the live backend of Tartarus.Migration.Executor's host role,
  # which also answers decision queries and takes acknowledgements). Runs in the host's
  # server, on the server's state.

  alias Tartarus.Ledger
  alias Tartarus.Host.Agents
  alias Tartarus.Migration.{Executor, Messages}

  @behaviour Tartarus.Migration.Executor.Host

  # How often a host asks the sources of its parked copies.
  @ask_every 30_000

  @doc false
  # One event of the host's own part of the protocol (Tartarus.Migration.HostProtocol):
  # a decision query, acknowledgements, a copy that parks, the timer, a parked copy's answer.
  # Returns the server's state.
  @spec event(map(), term()) :: map()
  def event(state, event), do: Executor.host_event(event, state, __MODULE__)

  @doc false
  def count(state), do: Ledger.counter(state.host, :parked)

  # -- the executor's effects (the host role's live backend; the context: the server's state)

  @impl true
  def read(state, mig, id, _copy), do: {Ledger.decision_view(state.host, mig, id), state}

  @impl true
  def tell(state, pid, msg) do
    send(pid, msg)
    state
  end

  @impl true
  def acknowledge(state, mig, id, copy) do
    Ledger.acknowledge(state.host, mig, id, copy)
    state
  end

  @impl true
  def record(state, {:acked, mig}) do
    Tartarus.Host.Persistence.acked(state.host, mig)
    state
  end

  def record(state, {:resolved, mig, copy}) do
    Tartarus.Host.Persistence.resolved(state.host, mig, copy)
    state
  end

  # Only the copy itself, found as its agent's arriving process here, may hand over its record.
  @impl true
  def park(state, mig, copy, env, src, kind, {pid, _}) do
    cond do
      not Ledger.arriving?(state.host, env.id, pid) -> {:not_here, state}
      Ledger.park(state.host, mig, copy, env, src, kind) and count(state) == 1 -> {:first, state}
      true -> {:more, state}
    end
  end

  @impl true
  def reply_call(state, from, answer) do
    GenServer.reply(from, answer)
    state
  end

  @impl true
  def arm_ask(state) do
    Tartarus.Clock.send_after(self(), :"$tartarus_ask_parked", @ask_every)
    state
  end

  @impl true
  def read_parked(state), do: {Ledger.parked(state.host), state}

  @impl true
  def ask(state, src, {mig, id, copy}) do
    with {:ok, pid} <- Tartarus.Host.whereis(src),
         do: send(pid, Messages.decision_query(mig, id, copy, self()))

    state
  end

  @impl true
  def fetch_parked(state, mig, copy), do: {Ledger.fetch_parked(state.host, mig, copy), state}

  @impl true
  def dropped(state) do
    Ledger.count(state.host, :dropped)
    state
  end

  @impl true
  def unpark(state, mig, copy) do
    Ledger.unpark(state.host, mig, copy)
    state
  end

  @impl true
  def revive(state, mig, copy, env, src, kind) do
    {mig, copy} = Tartarus.Fault.point(:reviving, {mig, copy})

    case Agents.start_agent(state, env, {:revived, mig, copy, src, kind}) do
      {:ok, pid, state} -> {{:ok, pid}, state}
      {:error, _reason, state} -> {:error, state}
    end
  end

  @impl true
  def arriving(state, id, pid) do
    Ledger.put_arriving(state.host, id, pid)
    state
  end
end
