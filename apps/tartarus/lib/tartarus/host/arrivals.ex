defmodule Tartarus.Host.Arrivals do
  @moduledoc false
  # A host's admission of arriving agents: the destination side of the hand-off
  # (Tartarus.Migration.Protocol.destination_step/2 decides; this module carries out its
  # actions: check the prepare's trust, size, code, capacity and the host's admission policy,
  # create the paused copy, journal it, answer `prepared`, `need` or `refused`). It runs in
  # the host's server (Tartarus.Host.Server), on the server's state.

  require Tartarus.Events
  alias Tartarus.{Clock, CodeCache, Envelope, Events, Ledger}
  alias Tartarus.Host.Agents
  alias Tartarus.Migration.Executor

  # Paused (and parked) copies a host without an admission policy holds at most (with a
  # policy they count against its max_resident_agents).
  @max_paused 10_000

  @behaviour Tartarus.Migration.Executor

  @doc false
  # One event of admission (Protocol.destination_step/2, carried out by
  # Tartarus.Migration.Executor with this module as its backend); returns the server's state.
  def admission(state, event) do
    {dest, state} = Executor.destination_event(state.dest, event, state, __MODULE__)
    %{state | dest: dest}
  end

  # -- the executor's effects (the destination's backend) -----------------------------------

  @impl Executor
  def check(state, p) do
    env = p.env

    {verdict, state} =
      with :ok <- trusted(state, p),
           # No copy this host could not journal (a full disk): refused, the source keeps it.
           :ok <- Tartarus.Host.Persistence.healthy(state.host),
           :ok <- heap_fits(state, env),
           :ok <- capacity(state),
           :ok <- prepare(state, env, p.manifest, p.code),
           {:ok, state} <- policy(state, p.src, env) do
        {:ok, state}
      else
        {:need, mods} -> {{:need, mods}, state}
        {:error, reason} -> {{:error, reason}, state}
      end

    {verdict, copy_token(state.host), state}
  end

  @impl Executor
  def probe(state, p, _copy, pid) do
    {Ledger.arriving?(state.host, p.env.id, pid), state}
  end

  @impl Executor
  def create(state, p, copy) do
    env = Tartarus.Fault.point(:admitting, p.env)

    case Agents.start_agent(state, env, {:paused, p.mig, copy, p.src, p.kind, p.s_pid}) do
      {:ok, pid, state} ->
        # Findable (messages to it wait until it starts).
        Ledger.put_arriving(state.host, env.id, pid)
        {{:ok, pid}, state}

      {:error, reason, state} ->
        {{:error, reason}, state}
    end
  end

  # Durable before `prepared` leaves.
  @impl Executor
  def journal(state, {:in_doubt, mig, env, src, kind, copy}) do
    Tartarus.Host.Persistence.in_doubt(state.host, mig, env, src, kind, copy)
    state
  end

  @impl Executor
  def send(state, pid, msg) do
    if is_pid(pid), do: Kernel.send(pid, msg)
    state
  end

  @impl Executor
  def refuse(state, p, reason), do: refuse(state, p.s_pid, p.mig, p.env, p.src, reason)

  @doc false
  # Paused copies of this host (monitored agents that are not resident).
  def paused(state), do: map_size(state.monitors) - Ledger.counter(state.host, :resident)

  # Unique across this host's runs (its incarnation is random per run); it names a copy, it
  # does not authenticate anyone (the seal does, for the prepare).
  defp copy_token(host),
    do: <<binary_part(host.incarnation, 0, 8)::binary, :erlang.unique_integer([:positive])::64>>

  defp capacity(%{admission: nil} = state) do
    if paused(state) + Ledger.counter(state.host, :parked) < @max_paused,
      do: :ok,
      else: {:error, {:busy, :paused_copies}}
  end

  defp capacity(_state), do: :ok

  # An agent whose state alone would not fit in the host's per-agent heap limit is refused
  # here, not killed after its source committed.
  defp heap_fits(%{host: %{opts: %{max_heap_size: :infinity}}}, _env), do: :ok

  defp heap_fits(%{host: %{opts: %{max_heap_size: words}}}, env) do
    size = :erts_debug.flat_size(env)
    if size * 2 <= words, do: :ok, else: {:error, {:too_large_for_heap, size, words}}
  end

  defp trusted(state, p) do
    case state.host.opts.security do
      %{trust: trust} -> Tartarus.Security.check_prepare(p, trust)
      _ -> :ok
    end
  end

  # The host's admission policy (Tartarus.Security.Admission), if it has one.
  defp policy(%{admission: nil} = state, _src, _env), do: {:ok, state}

  defp policy(state, src, env) do
    request = %{
      source: src,
      envelope_bytes: :erlang.external_size(env),
      payload_bytes: :erlang.external_size({env.state, env.payload}),
      hops: env.hops + 1,
      # Paused copies count: a stranger's prepares cannot hold more than the limit.
      resident: map_size(state.monitors) + Ledger.counter(state.host, :parked)
    }

    case Tartarus.Security.Admission.admit(
           state.admission,
           request,
           Clock.monotonic_time(:millisecond)
         ) do
      {:ok, admission} -> {:ok, %{state | admission: admission}}
      {:error, _} = error -> error
    end
  end

  defp prepare(_state, env, manifest, code) do
    with :ok <- check_ttl(env),
         :ok <- load_code(code) do
      CodeCache.check(manifest)
    end
  end

  defp check_ttl(%Envelope{ttl: :infinity}), do: :ok
  defp check_ttl(%Envelope{hops: hops, ttl: ttl}) when hops < ttl, do: :ok
  defp check_ttl(%Envelope{hops: hops}), do: {:error, {:ttl_expired, hops}}

  defp load_code([]), do: :ok
  defp load_code(code), do: CodeCache.load(code)

  @doc false
  # Refuses a prepare: the source hears why; nothing was created.
  def refuse(state, s_pid, mig, env, src, reason) do
    if is_pid(s_pid), do: Kernel.send(s_pid, Tartarus.Migration.Messages.refused(mig, reason))
    agent = with %{id: id} when is_binary(id) <- env, do: id, else: (_ -> nil)
    src = if Tartarus.Host.address?(src), do: src

    Events.emit(
      state.host,
      %{type: :refused, host: state.host.ref, agent: agent, from: src, reason: reason},
      refused: 1
    )

    state
  end

  # Acknowledgements per message (the first arrival after a flush arms the next, see
  # Tartarus.Migration.Arrival).
  @ack_batch 1_000

  @doc false
  # Sends the acknowledgements of this host's arrivals, one batch per source host: a timer
  # that only tells sources they may forget their commits (it decides nothing).
  def flush_acks(host) do
    :atomics.put(host.acks_armed, 1, 0)
    flush_acks(host.acks, :ets.first(host.acks))
  end

  defp flush_acks(_table, :"$end_of_table"), do: :ok

  defp flush_acks(table, src) do
    next = :ets.next(table, src)
    acks = table |> :ets.take(src) |> Enum.map(&elem(&1, 1))

    # A source host that is gone needs no acknowledgement (a restarted one keeps the commits
    # it journaled: they then stay, which is safe).
    with {:ok, pid} <- Tartarus.Host.whereis(src) do
      acks
      |> Enum.chunk_every(@ack_batch)
      |> Enum.each(&Kernel.send(pid, Tartarus.Migration.Messages.acks(&1)))
    end

    flush_acks(table, next)
  end
end
