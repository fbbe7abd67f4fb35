defmodule Tartarus.Host.Arrivals do
  @moduledoc false
  # A host's admission of arriving agents: the destination side of the hand-off
  # (Tartarus.Migration.Protocol.destination_step/2 decides; this module carries out its
  # actions: check the prepare's trust, size, code, capacity and the host's admission policy,
  # create the paused copy, journal it, answer `prepared`, `need` or `refused`).
  #
  # It runs in a process of its own for each prepare, not in the host's server: spawned with
  # the prepare as its argument (admit/2) by the source when the host is on its node, else
  # by the node's door (Tartarus.Host.ArrivalDoor), which the source sends the prepare to
  # (one distribution message, as a send to the server was); a prepare sent to the server
  # (a replay, a test) is handed to one the same way (admit_spawn/2). Admitted, that process
  # becomes the paused copy itself (Agent.Server.become/4) and answers `prepared`; the
  # server hears of it by an asynchronous {:"$tartarus_adopt", ...} and monitors it from
  # then on, as it does a locally created agent. So arrivals do not queue behind one process
  # per host. What admission shares lives in the host's ledger, updated atomically:
  # its memory of prepares (one admission per migration at a time, Ledger.seen_claim/2),
  # the count of the host's agents with a reservation per admission under way
  # (Ledger.reserve_admission/1: concurrent admissions never take the same last place), and
  # the rate buckets (Ledger.swap_bucket/4, a compare-and-swap).

  require Tartarus.Events
  alias Tartarus.{Clock, CodeCache, Envelope, Events, Ledger}
  alias Tartarus.Migration.{Executor, Messages, Protocol}

  # Paused (and parked) copies a host without an admission policy holds at most (with a
  # policy they count against its max_resident_agents).
  @max_paused 10_000

  @behaviour Tartarus.Migration.Executor.Destination

  # An admission runs at high priority, as the host's server did when it admitted: among
  # thousands of runnable agents (a clone storm) a prepare is answered, refused when the
  # host is full, rather than left to time out. Its work is short and bounded; the copy it
  # becomes runs at normal priority (Agent.Server.become/4).
  @spawn_opts [priority: :high]

  @doc false
  # Sends `prepare` to host `dest` (its server is `dest_pid`): its admission is spawned on
  # the host's node, the prepare as the argument. On this node directly; on another, by the
  # node's door (Tartarus.Host.ArrivalDoor, one distribution message: a spawn_request over
  # distribution would add a fourth, its spawn reply).
  @spec send_prepare(term(), pid(), tuple()) :: :ok
  def send_prepare(dest, dest_pid, prepare) do
    node = node(dest_pid)

    if node == node() do
      _ = admit_spawn(dest, prepare)
      :ok
    else
      Kernel.send({:tartarus_arrivals, node}, {:"$tartarus_arrive", dest, prepare})
      :ok
    end
  end

  @doc false
  # Spawns the admission of `prepare` for host `dest` (an address or a host's map) of this
  # node: the source's, the node's door's or the host server's (a replay) way in.
  @spec admit_spawn(term(), tuple()) :: pid()
  def admit_spawn(%{ref: ref}, prepare), do: admit_spawn(ref, prepare)

  def admit_spawn(dest, prepare),
    do: :erlang.spawn_opt(__MODULE__, :admit, [dest, prepare], @spawn_opts)

  @doc false
  # The admission of one prepare at host `dest` of this node (the process's entry point):
  # the copy it makes is this process, which then runs as the paused agent; otherwise it
  # ends once it answered.
  @spec admit(term(), tuple()) :: :ok | no_return()
  def admit(dest, {:"$tartarus_prepare", _, _, _, _, _, _, _, _} = msg) do
    with {:ok, host} <- Tartarus.Host.local(dest) do
      case admission(host, msg) do
        %{copy: {key, env, mode}} -> host.become.(host, key, env, mode)
        %{reserved: true} -> Ledger.release_admission(host)
        _ -> :ok
      end
    end

    :ok
  end

  def admit(_dest, _other), do: :ok

  defp admission(host, {:"$tartarus_prepare", s_pid, mig, src, _, _, env, _, _} = msg) do
    msg = Tartarus.Fault.point(:prepare_received, msg)
    admission = host.opts[:admission]

    case Tartarus.Wire.check_prepare(msg, message_limit(admission)) do
      :ok ->
        {:prepare, p} = Messages.classify(msg)
        ctx = %{host: host, admission: admission, reserved: false, copy: nil}
        d = Protocol.destination(store: {Ledger, Ledger.admission_memory(host)})
        {_d, ctx} = Executor.destination_event(d, {:prepare, p}, ctx, __MODULE__)
        ctx

      {:error, reason} ->
        refuse(%{host: host}, s_pid, mig, env, src, reason)
    end
  rescue
    # The host stopped meanwhile (its ledger went with its warden): nothing to admit into.
    e in ArgumentError -> if Ledger.exists?(host), do: reraise(e, __STACKTRACE__), else: %{}
  end

  defp message_limit(nil), do: :infinity
  defp message_limit(admission), do: Tartarus.Security.Admission.max_message_bytes(admission)

  # -- the executor's effects (the destination's backend) -----------------------------------

  @impl Executor.Destination
  def check(ctx, p) do
    env = p.env

    {verdict, ctx} =
      with :ok <- trusted(ctx, p),
           # No copy this host could not journal (a full disk): refused, the source keeps it.
           :ok <- Tartarus.Host.Persistence.healthy(ctx.host),
           :ok <- heap_fits(ctx, env),
           :ok <- prepare(ctx, env, p.manifest, p.code),
           # Last: the place it reserves is given back if anything else refuses.
           {:ok, ctx} <- room(ctx, p.src, env) do
        {:ok, ctx}
      else
        {:need, mods} -> {{:need, mods}, ctx}
        {:error, reason} -> {{:error, reason}, ctx}
      end

    {verdict, copy_token(ctx.host), ctx}
  end

  @impl Executor.Destination
  def probe(ctx, p, _copy, pid) do
    {Ledger.arriving?(ctx.host, p.env.id, pid), ctx}
  end

  # The copy is this process (it becomes the agent once admission is done, admit/2):
  # recorded as the host's (which ends the reservation) and findable (messages to it wait
  # until it starts); the host's server hears of it.
  @impl Executor.Destination
  def create(ctx, p, copy) do
    host = ctx.host
    env = fault(:admitting, p.env, host)

    if Ledger.stopping?(host) do
      {{:error, :host_stopping}, ctx}
    else
      key = make_ref()
      entry = %{id: env.id, key: key, restarts: 0, owner: env.owner, create: false}
      Ledger.put_proc(host, self(), entry)
      Ledger.release_admission(host)
      Ledger.put_arriving(host, env.id, self())
      Kernel.send(Tartarus.Host.server(host), {:"$tartarus_adopt", self(), entry})
      mode = {:paused, p.mig, copy, p.src, p.kind, p.s_pid}
      {{:ok, self()}, %{ctx | reserved: false, copy: {key, env, mode}}}
    end
  end

  # A fault hook that raises (a test's) gives the reservation back first.
  defp fault(point, value, host) do
    Tartarus.Fault.point(point, value)
  catch
    kind, reason ->
      Ledger.release_admission(host)
      :erlang.raise(kind, reason, __STACKTRACE__)
  end

  # Durable before `prepared` leaves.
  @impl Executor.Destination
  def journal_in_doubt(ctx, {:in_doubt, mig, env, src, kind, copy}) do
    Tartarus.Host.Persistence.in_doubt(ctx.host, mig, env, src, kind, copy)
    ctx
  end

  @impl Executor.Destination
  def answer(ctx, pid, msg) do
    if is_pid(pid), do: Kernel.send(pid, msg)
    ctx
  end

  @impl Executor.Destination
  def refuse(ctx, p, reason), do: refuse(ctx, p.s_pid, p.mig, p.env, p.src, reason)

  @doc false
  # Paused copies of this host (monitored agents that are not resident).
  def paused(state), do: map_size(state.monitors) - Ledger.counter(state.host, :resident)

  # Unique across this host's runs (its incarnation is random per run); it names a copy, it
  # does not authenticate anyone (the seal does, for the prepare).
  defp copy_token(host),
    do: <<binary_part(host.incarnation, 0, 8)::binary, :erlang.unique_integer([:positive])::64>>

  # Room for one more agent, reserved (Ledger.reserve_admission/1): `held` counts the host's
  # agent processes (paused copies included) and the admissions under way before this one.
  defp room(ctx, src, env) do
    held = Ledger.reserve_admission(ctx.host)

    case policy(ctx, src, env, held) do
      {:ok, ctx} ->
        {:ok, %{ctx | reserved: true}}

      error ->
        Ledger.release_admission(ctx.host)
        error
    end
  end

  # Without an admission policy: a bound on paused and parked copies.
  defp policy(%{admission: nil} = ctx, _src, _env, held) do
    paused = held - Ledger.counter(ctx.host, :resident)

    if paused + Ledger.counter(ctx.host, :parked) < @max_paused,
      do: {:ok, ctx},
      else: {:error, {:busy, :paused_copies}}
  end

  # The host's admission policy (Tartarus.Security.Admission): its source's bucket is taken
  # from the ledger and put back only if no other admission changed it meanwhile (else the
  # decision is made again on the new bucket).
  defp policy(ctx, src, env, held) do
    request = %{
      source: src,
      envelope_bytes: :erlang.external_size(env),
      payload_bytes: :erlang.external_size({env.state, env.payload}),
      hops: env.hops + 1,
      # Paused copies count: a stranger's prepares cannot hold more than the limit.
      resident: held + Ledger.counter(ctx.host, :parked)
    }

    take_token(ctx, request)
  end

  defp take_token(ctx, %{source: src} = request) do
    old = with {:ok, b} <- Ledger.bucket(ctx.host, src), do: b, else: (:error -> nil)
    admission = %{ctx.admission | buckets: if(old, do: %{src => old}, else: %{})}
    now = Clock.monotonic_time(:millisecond)

    case Tartarus.Security.Admission.admit(admission, request, now) do
      {:ok, admission} ->
        if Ledger.swap_bucket(ctx.host, src, old, Map.get(admission.buckets, src)) do
          if old == nil, do: prune_buckets(ctx, now)
          {:ok, ctx}
        else
          take_token(ctx, request)
        end

      {:error, _} = error ->
        error
    end
  end

  # Full buckets mean the same as none: past @prune_above sources they are dropped (every
  # @prune_every new ones, so the cost stays amortized), as Admission bounds its own map.
  @prune_above 1_024
  @prune_every 256

  defp prune_buckets(ctx, now) do
    n = Ledger.counted(ctx.host, :buckets)

    if n > @prune_above and rem(n, @prune_every) == 0 do
      buckets = Ledger.buckets(ctx.host)
      kept = Tartarus.Security.Admission.prune(%{ctx.admission | buckets: buckets}, now).buckets

      for {src, b} <- buckets,
          not is_map_key(kept, src),
          do: Ledger.swap_bucket(ctx.host, src, b, nil)
    end

    :ok
  end

  # An agent whose state alone would not fit in the host's per-agent heap limit is refused
  # here, not killed after its source committed.
  defp heap_fits(%{host: %{opts: %{max_heap_size: :infinity}}}, _env), do: :ok

  defp heap_fits(%{host: %{opts: %{max_heap_size: words}}}, env) do
    size = :erts_debug.flat_size(env)
    if size * 2 <= words, do: :ok, else: {:error, {:too_large_for_heap, size, words}}
  end

  defp trusted(ctx, p) do
    case ctx.host.opts.security do
      %{trust: trust} -> Tartarus.Security.check_prepare(p, trust)
      _ -> :ok
    end
  end

  defp prepare(_ctx, env, manifest, code) do
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
