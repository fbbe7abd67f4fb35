defmodule Tartarus.Migration.Source do
  @moduledoc false
  # The source side of a hand-off, run by the agent's own process (so hand-offs of many
  # agents proceed in parallel): it sends `prepare`, waits for the destination's answer and
  # hands each event to Tartarus.Migration.Executor, which decides through
  # Tartarus.Migration.Protocol and orders the effects. This module is the executor's live
  # backend: the host's ledger (ETS), its journal, real sends, the agent's mailbox.
  #
  # attempt/4 starts a hand-off and returns {:wait, data} (the agent's state machine is then
  # :handing_off and hands this module each message, event/2, and its deadline, step/2) or
  # {:failed, reason, data}; step/2 returns {:wait, data} or {outcome, by, data} with outcome
  # {:moved, new_pid}, {:cloned, clone_id} or {:failed, reason} for `by` (who started it, see
  # Tartarus.Agent.Actions). `data` is the agent process's state (Tartarus.Agent.Server);
  # the hand-off's own state is data.handoff while it lasts.

  @behaviour Tartarus.Migration.Executor.Source

  require Tartarus.Events
  alias Tartarus.{Clock, CodeCache, Envelope, Events, Ledger, Strategy}
  alias Tartarus.Migration.{Executor, Messages, Protocol}

  # -- before the hand-off: where to, may it go, with what code ---------------------

  @doc false
  # A move or clone of the agent whose process state is `data`, to `dest_spec` (a host or a
  # strategy); `by` = {kind, dest_spec, :act | {:call, from}}: a caller waits for the outcome
  # (answered by the destination). Returns {:wait, data} or {:failed, reason, data}.
  @spec attempt(map(), :move | :clone, term(), term()) ::
          {:wait, map()} | {:failed, term(), map()}
  def attempt(data, kind, dest_spec, by) do
    env = data.env

    # A host whose journal cannot be written (a full disk) starts no hand-off: it could not
    # make its decision durable.
    with :ok <- movable(env, kind),
         :ok <- Tartarus.Host.Persistence.healthy(data.host),
         {:ok, dest, data} <- resolve(data, dest_spec),
         :ok <- linked(data, dest),
         :ok <- Envelope.portable?(%{state: env.state, payload: env.payload.data}),
         {:ok, manifest} <- CodeCache.manifest(Envelope.modules(env)),
         {:ok, dest_pid} <- Tartarus.Host.whereis(dest),
         {:ok, data} <- link_loss(data, dest) do
      run(data, kind, dest, dest_pid, manifest, by)
    else
      {:error, reason} -> {:failed, reason, data}
      {:error, reason, data} -> {:failed, reason, data}
    end
  end

  defp movable(%Envelope{static: true}, :move), do: {:error, :static_agent}
  defp movable(_env, _kind), do: :ok

  defp resolve(data, :here), do: {:ok, data.host.ref, data}

  defp resolve(data, spec) do
    if Strategy.strategy?(spec) do
      info = %{
        here: data.host.ref,
        neighbours: Ledger.neighbours(data.host),
        visits: data.env.visits,
        gradients: gradients(data, spec)
      }

      rng = :rand.seed_s(data.env.rng)

      case Strategy.choose(spec, info, rng) do
        {:ok, dest, rng} ->
          {:ok, dest, %{data | env: %{data.env | rng: :rand.export_seed_s(rng)}}}

        {:error, reason} ->
          {:error, reason}
      end
    else
      # A bare name: the neighbour of that name, else this node's host (Host.resolve/2).
      if Tartarus.Host.address?(spec) do
        with {:ok, dest} <- Tartarus.Host.resolve(spec, Ledger.neighbours(data.host)),
             do: {:ok, dest, data}
      else
        {:error, {:bad_destination, spec}}
      end
    end
  end

  defp gradients(data, {:gradient, signal}),
    do: %{signal => Tartarus.Signal.strategy_gradient(data.host, signal)}

  defp gradients(_data, _spec), do: %{}

  defp linked(%{host: %{ref: ref}}, ref), do: :ok

  defp linked(data, dest) do
    if data.host.opts.strict_links and dest not in Ledger.neighbours(data.host),
      do: {:error, {:no_link, dest}},
      else: :ok
  end

  # The node's transport (Tartarus.Transport), if an emulator installed one: it may delay the
  # hand-off or fail it, drawing from the agent's own random stream.
  defp link_loss(data, dest) do
    case Tartarus.Transport.installed() do
      nil ->
        {:ok, data}

      transport ->
        case transport.hand_off(data.host, dest, data.env.rng) do
          {:ok, rng} -> {:ok, put_in(data.env.rng, rng)}
          {:error, reason, rng} -> {:error, reason, put_in(data.env.rng, rng)}
        end
    end
  end

  # -- the hand-off --------------------------------------------------------------

  @doc false
  @spec run(map(), :move | :clone, term(), pid(), list(), term()) :: {:wait, map()}
  def run(data, kind, dest, dest_pid, manifest, by) do
    host = data.host
    mig = {host.incarnation, make_ref()}
    out = Tartarus.Fault.point(:outgoing, outgoing(data.env, kind))

    prepare =
      seal(
        Messages.prepare(
          self(),
          mig,
          host.ref,
          Tartarus.Host.server(host),
          kind,
          out,
          manifest,
          []
        ),
        host
      )

    x = %{
      data: %{data | handoff: nil},
      dest: dest,
      dest_pid: dest_pid,
      mref: nil,
      manifest: manifest,
      prepare: prepare,
      out: out,
      code_bytes: 0,
      by: by
    }

    s = Protocol.source(mig, kind, dest_pid, notify(by), data.env.id, out.id)
    # The hand-off record (before `prepare` leaves), the watch, the prepare.
    {:wait, s, x} = Executor.source_event(s, :begin, x, __MODULE__)
    {:wait, %{x.data | handoff: {s, Map.delete(x, :data)}}}
  end

  # Who waits for the outcome: the caller of Tartarus.move/2 or clone/2 (answered by the
  # destination), or nobody (the agent's own action).
  defp notify({_kind, _dest, {:call, from}}), do: from
  defp notify(_by), do: nil

  @doc false
  # The event a message is for the hand-off of the agent whose state is `data`, or nil (not
  # for it: the agent's state machine keeps it).
  @spec event(map(), term()) :: term() | nil
  def event(%{handoff: {%{mig: mig}, %{mref: mref}}}, msg) do
    case msg do
      {:"$tartarus_prepared", ^mig, _, _} -> Messages.classify(msg)
      {:"$tartarus_refused", ^mig, _} -> Messages.classify(msg)
      {:"$tartarus_need", ^mig, _} -> Messages.classify(msg)
      {:DOWN, ^mref, :process, _, reason} -> {:down, reason}
      {:nodedown, node} when mref == {:node, node} -> {:down, :noconnection}
      _ -> nil
    end
  end

  @doc false
  # An event ({type, content}) of a handing-off agent: {:step, event} (its hand-off's own:
  # step/2), else what Tartarus.Agent.Held.keep/2 does with it (held, postponed, taken,
  # refused). Tartarus.Agent.Server in :handing_off and the model check both route by it.
  @spec route(map(), {term(), term()}) ::
          {:step, term()} | {:held, map()} | {:postponed, map()} | :taken | :refused
  def route(data, {:info, msg} = event) do
    case event(data, msg) do
      nil -> Tartarus.Agent.Held.keep(data, event)
      e -> {:step, e}
    end
  end

  def route(data, event), do: Tartarus.Agent.Held.keep(data, event)

  @doc false
  # One event of the hand-off (event/2's, or :timeout at its deadline): {:wait, data} or
  # {outcome, by, data} (see the top of this module).
  @spec step(map(), term()) :: {:wait, map()} | {term(), term(), map()}
  def step(%{handoff: {s, x}} = data, event) do
    case Executor.source_event(s, event, Map.put(x, :data, %{data | handoff: nil}), __MODULE__) do
      {:wait, s, x} -> {:wait, %{x.data | handoff: {s, Map.delete(x, :data)}}}
      {:done, outcome, s, x} -> done(outcome, s, x)
    end
  end

  defp done({:committed, _copy, new_pid}, %{kind: :move}, x),
    do: {{:moved, new_pid}, x.by, x.data}

  # The parent's stream advanced by the fork that seeded the clone's (see outgoing/2).
  defp done({:committed, _copy, _pid}, %{kind: :clone}, x) do
    data = x.data
    data = put_in(data.env.rng, elem(Tartarus.Random.fork(data.env.rng), 1))
    {{:cloned, x.out.id}, x.by, data}
  end

  defp done({:failed, reason}, _s, x) do
    if match?({:host_down, _}, reason), do: Tartarus.Host.Directory.forget(x.dest)
    {{:failed, reason}, x.by, x.data}
  end

  # -- the executor's effects --------------------------------------------------------

  # Before `prepare` leaves: the migration is undecided for whoever asks.
  @impl true
  def begin_handoff(x, mig) do
    Ledger.begin_handoff(x.data.host, x.data.env.id, mig)
    x
  end

  @impl true
  def watch(x), do: %{x | mref: watch_pid(x.dest_pid)}

  # To a process spawned for it at the destination, not to the host's server (admission
  # does not queue behind one process per host, Tartarus.Host.Arrivals).
  @impl true
  def send_prepare(x) do
    Tartarus.Host.Arrivals.send_prepare(x.dest, x.dest_pid, x.prepare)
    x
  end

  @impl true
  def settle(x, {:prepared, pid}) do
    unwatch(x.mref)
    Tartarus.Fault.point(:prepared, pid)
    x
  end

  def settle(x, :failed) do
    unwatch(x.mref)
    x
  end

  @impl true
  def decide(x, mig, copy),
    do: {Ledger.decide(x.data.host, mig, {:committed, copy}), x}

  @impl true
  def journal(x, {:decision, mig, id, copy}) do
    Tartarus.Host.Persistence.committed(x.data.host, mig, id, copy)
    x
  end

  def journal(x, {:forget, id}) do
    Tartarus.Host.Persistence.forget(x.data.host, id)
    x
  end

  @impl true
  def pointer_put(x, mig, copy, notify) do
    env = x.data.env
    Ledger.put_pointer(x.data.host, env.id, env.name, x.dest, mig, copy, notify)
    x
  end

  @impl true
  def leave(x) do
    host = x.data.host
    Ledger.forget_resident(host, self())
    # No longer one of the host's agents, at once: admission counts the host's agent
    # processes (Ledger.reserve_admission/1) and must not count this one until the host's
    # server has taken its :DOWN (with a thousand agents moving, that server ran a thousand
    # :DOWNs behind, and arrivals were refused {:too_many_agents, _} while the host held
    # half its limit). Its snapshot goes too: nothing restarts it here now.
    Ledger.drop_proc(host, self())
    Ledger.drop_snapshot(host, x.data.key)
    x
  end

  @impl true
  def end_handoff(x, mig) do
    Ledger.end_handoff(x.data.host, x.data.env.id, mig)
    x
  end

  # The commit carries the messages this process took and had not handled, then those that
  # reached it: kept while it handed off (data.held), then still in its mailbox (drained
  # without waiting).
  @impl true
  def hand_over(x, pid, {:"$tartarus_commit", mig, copy, notify, nil}) do
    {handover, data} = Tartarus.Agent.Held.hand_over(x.data, drain([]))
    send(%{x | data: data}, pid, Messages.commit(mig, copy, notify, handover))
  end

  @impl true
  def send(x, pid, msg) do
    if elem(msg, 0) == :"$tartarus_commit", do: Tartarus.Fault.point(:committing, pid)
    Kernel.send(pid, msg)
    x
  end

  @impl true
  def fetch_code(x, mods), do: {Tartarus.CodeShipping.binaries(x.manifest, mods), x}

  @impl true
  def resend(x, code) do
    Tartarus.Host.Arrivals.send_prepare(x.dest, x.dest_pid, Messages.with_code(x.prepare, code))
    %{x | code_bytes: max(:erlang.external_size(code), 1)}
  end

  @impl true
  def committed(x, kind, _mig, _copy) do
    %{data: data, out: out, code_bytes: code_bytes} = x
    host = data.host
    bytes = :erlang.external_size(out)

    if kind == :move do
      emit(
        host,
        %{type: :departure, agent: data.env.id, to: x.dest, bytes: bytes, code_bytes: code_bytes},
        departures: 1,
        bytes: bytes + code_bytes,
        code_bytes: code_bytes
      )
    else
      emit(host, %{type: :clone, agent: data.env.id, clone: out.id, to: x.dest, bytes: bytes},
        clones: 1,
        bytes: bytes + code_bytes
      )
    end

    x
  end

  # -- helpers -----------------------------------------------------------------------

  defp emit(host, event, counts), do: Events.emit(host, Map.put(event, :host, host.ref), counts)

  defp drain(acc) do
    receive do
      {:"$tartarus_msg", _, _, _} = m -> drain([m | acc])
    after
      0 -> Enum.reverse(acc)
    end
  end

  defp seal(prepare, host) do
    case host.opts.security do
      %{keys: keys} -> Tartarus.Security.seal_prepare(prepare, keys)
      _ -> prepare
    end
  end

  # A local destination host is monitored; for a remote one the node is (a node monitor
  # costs no messages on the wire, a remote process monitor two per hand-off). A host that
  # dies while its node lives is caught by the timeout.
  defp watch_pid(pid) when node(pid) == node(), do: Process.monitor(pid)

  defp watch_pid(pid) do
    Node.monitor(node(pid), true)
    {:node, node(pid)}
  end

  defp unwatch({:node, node}) do
    Node.monitor(node, false)

    receive do
      {:nodedown, ^node} -> :ok
    after
      0 -> :ok
    end
  end

  defp unwatch(mref), do: Process.demonitor(mref, [:flush])

  defp outgoing(env, :move), do: %{env | departed_at: Clock.system_time(:microsecond)}

  defp outgoing(env, :clone) do
    # (Not the pooled new_id/0: an agent's process keeps no dictionary key.)
    id = Envelope.new_id(:unpooled)

    %{
      env
      | id: id,
        name: Envelope.clone_name(env.name, id),
        clone_of: env.id,
        rng: elem(Tartarus.Random.fork(env.rng), 0),
        departed_at: Clock.system_time(:microsecond)
    }
  end
end
