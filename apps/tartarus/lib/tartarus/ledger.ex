defmodule Tartarus.Ledger do
  @moduledoc false
  # Reads and writes of a host's ledger table. The host server owns the table; agents write
  # their own residence and departure records (public table), so the hot path of a migration
  # does not go through the host server.
  #
  # Keys:
  #   :neighbours                 [host]
  #   {:link, host}               %{latency_ms:, loss:}
  #   {:agent, pid}               {_, id, name, module}      a resident agent
  #   {:fwd, id}                  {_, :handoff, mig, source_pid}
  #                               an undecided hand-off (move or clone) of agent id, resident
  #                               here; one record, written before `prepare` leaves. A
  #                               committed move replaces it with the forwarding pointer in
  #                               one write (the pointer is the move's decision); an abort
  #                               deletes it; a committed clone writes its decision first.
  #   {:fwd, id | name}           {_, dest_host, at_us, {mig, copy} | :acked | :name, notify}
  #                               (an id's pointer names its migration until the copy
  #                               acknowledges; a name's pointer never stands for a decision)
  #   {:parked, {mig, copy}}      {_, env, src, kind}        a parked in-doubt copy (destination)
  #   :parked                     n                          how many
  #   {:arriving, id}             {_, pid}                   a paused copy (destination)
  #   {:decision, mig}            {_, {:committed, copy}}    a clone's commit, until the clone's
  #                                                          ack (and, after a restart with
  #                                                          persistence, every journaled commit)
  #   {:count, name}              {_, n}                     e.g. :dropped (unexpected messages)
  #   :population                 {_, resident, visits}      counters
  #   {:count, name}              {_, n}
  #   {:hop, slot}                {_, hop_us}                ring of recent hop times
  #   {:seen, mig}                {_, what, seq}             admission's memory of a prepare
  #                                                          (Migration.Protocol.destination/1)
  #   {:seen_order, seq}          {_, mig}                   its age, oldest forgotten first
  #   :seen_range                 {_, first, next}           the seqs remembered: first..next-1

  @slots 1024

  # A host that stops takes its table with it; a message already on its way to the host
  # (a signal the overlay relays, say) then finds no table: a stopped host has no
  # neighbours, and its reader carries on.
  def neighbours(%{ledger: l}) do
    case :ets.lookup(l, :neighbours) do
      [{_, ns}] -> ns
      [] -> []
    end
  rescue
    ArgumentError -> []
  end

  def link(%{ledger: l}, dest) do
    case :ets.lookup(l, {:link, dest}) do
      [{_, props}] -> props
      [] -> nil
    end
  end

  # Admission's memory (Tartarus.Migration.Protocol.destination/1's `store:`): off the
  # host server's heap (10,000 remembered prepares are about 2.7 MB, which made every
  # collection of that heap a long one), and it outlives a restart of the server.
  def seen_fetch(ledger, mig) do
    case :ets.lookup(ledger, {:seen, mig}) do
      [{_, what, _seq}] -> {:ok, what}
      [] -> :error
    end
  end

  # Remembers `what` for `mig`; past `max` migrations the oldest is forgotten.
  def seen_put(ledger, mig, what, max) do
    case :ets.lookup(ledger, {:seen, mig}) do
      [{key, _, seq}] ->
        :ets.insert(ledger, {key, what, seq})

      [] ->
        {first, next} =
          case :ets.lookup(ledger, :seen_range) do
            [{_, first, next}] -> {first, next}
            [] -> {0, 0}
          end

        :ets.insert(ledger, [{{:seen, mig}, what, next}, {{:seen_order, next}, mig}])
        first = if next + 1 - first > max, do: seen_forget(ledger, first), else: first
        :ets.insert(ledger, {:seen_range, first, next + 1})
    end

    :ok
  end

  defp seen_forget(ledger, seq) do
    case :ets.take(ledger, {:seen_order, seq}) do
      [{_, mig}] -> :ets.delete(ledger, {:seen, mig})
      [] -> :ok
    end

    seq + 1
  end

  def register_resident(host, env, pid) do
    {name, _node} = host.ref

    case Tartarus.AgentTable.register(env.id, pid, name, env.name, env.module) do
      :ok ->
        :ets.insert(host.ledger, {{:agent, pid}, env.id, env.name, env.module})
        :ets.delete(host.ledger, {:fwd, env.id})
        if env.name, do: :ets.delete(host.ledger, {:fwd, env.name})
        :ets.update_counter(host.ledger, :population, [{2, 1}, {3, 1}])
        :ok

      {:error, _} = error ->
        error
    end
  end

  def forget_resident(host, pid) do
    case :ets.take(host.ledger, {:agent, pid}) do
      [{_, id, name, module}] ->
        Tartarus.AgentTable.unregister(id, pid, elem(host.ref, 0), name, module)
        :ets.update_counter(host.ledger, :population, {2, -1})
        true

      [] ->
        false
    end
  end

  # Before `prepare` leaves: the migration is undecided (Protocol.answer/3 says :unknown).
  # Keyed by the agent's id: a kill or crash of the agent finds it, and a source process runs
  # one hand-off at a time.
  def begin_handoff(host, id, mig),
    do: :ets.insert(host.ledger, {{:fwd, id}, :handoff, mig, self()})

  # An abort: the hand-off record goes with no commit written.
  def end_handoff(host, id, mig),
    do: :ets.delete_object(host.ledger, {{:fwd, id}, :handoff, mig, self()})

  # A clone's commit (before its hand-off record goes). Returns false if one was already
  # written (never: one writer).
  def decide(host, mig, decision), do: :ets.insert_new(host.ledger, {{:decision, mig}, decision})

  # The agent committed the move `mig` (copy `copy`) to `dest`: its forwarding pointer, which
  # names the commit for a destination that asks (see decision/4), replaces the hand-off
  # record in one write (then the agent stops being resident: forget_resident/2). `notify`
  # (a GenServer from, or nil) is who waits for the move to finish: a destination that
  # learns of the commit by asking (the commit message was lost) answers it.
  def put_pointer(host, id, name, dest, mig, copy, notify) do
    now = Tartarus.Clock.system_time(:microsecond)
    :ets.insert(host.ledger, {{:fwd, id}, dest, now, {mig, copy}, notify})
    if name, do: :ets.insert(host.ledger, {{:fwd, name}, dest, now, :name, nil})
  end

  # The agent `env` ended on this host (returned or stopped): the forwarding pointers it left
  # on the hosts it visited lead nowhere now. Each of those hosts is told once (through its
  # node's Tartarus.Host.Directory, without opening connections: a host on a node no longer
  # connected keeps its pointer), and drops them (forget_pointers/3). Only the hosts its
  # `visits` still remembers (the `max_visits` last) are told. Nothing else but `forward_ttl`
  # reclaims the pointer of an agent that ended elsewhere.
  def gone(host, env) do
    for {{name, node} = h, _} <- env.visits, h != host.ref do
      :erlang.send(
        {Tartarus.Host.Directory, node},
        {:"$tartarus_gone", name, env.id, env.name},
        [:noconnect]
      )
    end

    :ok
  end

  # Drops the forwarding pointers of agent `id` (and of its name) after it ended elsewhere.
  # An agent that ended ran as its last committed copy, so no paused copy can still ask
  # about a pointer's migration: a copy that does (a replay) is told aborted, which is
  # right. An agent resident here has no pointer here.
  def forget_pointers(host, id, name) do
    :ets.delete(host.ledger, {:fwd, id})
    if name, do: :ets.delete(host.ledger, {:fwd, name})
    :ok
  end

  # The answer to a paused copy `copy` of migration `mig` of agent `id` that asks this
  # (source) host: Tartarus.Migration.Protocol.answer/3 over what the ledger holds, read in
  # the protocol's order (hand-off record first).
  # `id` is the agent that left (for a clone, the clone's parent: `query_id/2`). One read
  # decides a move (its hand-off record, then its pointer, under one key); a clone's commit
  # is written before its hand-off record goes, so it is read second.
  def decision(host, mig, id, copy) do
    {handoff?, pointer} =
      case :ets.lookup(host.ledger, {:fwd, id}) do
        [{_, :handoff, ^mig, _pid}] -> {true, nil}
        [{_, _dest, _at, {m, c}, notify}] -> {false, {m, c, notify}}
        _ -> {false, nil}
      end

    decision =
      case :ets.lookup(host.ledger, {:decision, mig}) do
        [{_, d}] -> d
        [] -> nil
      end

    Tartarus.Migration.Protocol.answer(
      %{handoff?: handoff?, decision: decision, pointer: pointer},
      mig,
      copy
    )
  end

  # The committed copy `copy` of `mig` (agent `id`) runs: its commit record is no longer
  # needed. A clone's decision goes; a move's pointer stays for forwarding, marked :acked
  # (sweepable).
  def acknowledge(host, mig, id, copy) do
    l = host.ledger

    case :ets.lookup(l, {:fwd, id}) do
      [{key, dest, at, {^mig, ^copy}, _notify}] -> :ets.insert(l, {key, dest, at, :acked, nil})
      # A clone's (or, after a restart with persistence, a journaled) commit.
      _ -> :ets.delete_object(l, {{:decision, mig}, {:committed, copy}})
    end

    :ok
  end

  def count(%{ledger: l}, name),
    do: :ets.update_counter(l, {:count, name}, 1, {{:count, name}, 0})

  # After the agent `id` (process `pid`) died or was killed: its undecided hand-offs are
  # aborted (their records go; the process that could have committed them is dead). True if
  # the agent is still ours to restart, false if it had committed a move (it lives on at
  # the destination).
  #
  # A resident agent has no pointer here (its arrival deleted it), so a pointer under its id
  # means it committed a move; a hand-off record means an undecided one (or a clone's).
  def abort_pending(host, id, _pid) do
    case :ets.lookup(host.ledger, {:fwd, id}) do
      [{_, :handoff, _mig, _p} = record] ->
        :ets.delete_object(host.ledger, record)
        true

      [{_, _dest, _at, _decision, _notify}] ->
        false

      [] ->
        true
    end
  end

  # The hand-off record of agent `id`'s source process `pid`, which is gone.
  def drop_handoffs(host, id, pid),
    do: :ets.match_delete(host.ledger, {{:fwd, id}, :handoff, :_, pid})

  # The agent id a paused copy asks its source host about: the agent that left (a clone's
  # parent for a clone).
  def query_id(%{clone_of: parent}, :clone) when parent != nil, do: parent
  def query_id(env, _kind), do: env.id

  # The ring of recent hop times is an atomics array (slot 1: the sequence; slots 2..: the
  # times plus one, 0 for an empty slot): two atomic operations a hop, no table write.
  def new_hop_ring, do: :atomics.new(@slots + 1, [])

  def record_hop(%{hops: ring}, hop_us) do
    seq = :atomics.add_get(ring, 1, 1)
    :atomics.put(ring, 2 + rem(seq, @slots), hop_us + 1)
  end

  def hop_times(%{hops: ring}) do
    # Only the slots written so far: a host that saw 5 hops costs 5 reads, not @slots.
    case :atomics.get(ring, 1) do
      0 ->
        []

      seq when seq < @slots ->
        for k <- 1..seq, (t = :atomics.get(ring, 2 + rem(k, @slots))) > 0, do: t - 1

      _ ->
        for i <- 2..(@slots + 1), (t = :atomics.get(ring, i)) > 0, do: t - 1
    end
  end

  # Empties the ring (benchmarks measure a phase at a time).
  def reset_hops(%{hops: ring}) do
    for i <- 1..(@slots + 1), do: :atomics.put(ring, i, 0)
    :ok
  end

  # Resident agents and visits so far: one record, one update a hop.
  def counter(%{ledger: l}, :resident), do: :ets.lookup_element(l, :population, 2)
  def counter(%{ledger: l}, :visits), do: :ets.lookup_element(l, :population, 3)

  def counter(%{ledger: l}, key) do
    case :ets.lookup(l, key) do
      [{_, n}] -> n
      [] -> 0
    end
  end

  def residents(%{ledger: l}) do
    :ets.select(l, [
      {{{:agent, :"$1"}, :"$2", :"$3", :"$4"}, [], [{{:"$2", :"$3", :"$4", :"$1"}}]}
    ])
  end

  # Drops forwarding pointers written before `cutoff_us` (system time) that no longer
  # stand for a decision (acknowledged, or a name's): never one a paused copy may still need.
  def sweep_pointers(%{ledger: l}, cutoff_us) do
    :ets.select_delete(l, [
      {{{:fwd, :_}, :_, :"$1", :"$2", :_}, [{:<, :"$1", cutoff_us}, {:is_atom, :"$2"}], [true]}
    ])
  end

  def forwarding_pointers(%{ledger: l}) do
    :ets.select(l, [{{{:fwd, :"$1"}, :"$2", :_, :_, :_}, [], [{{:"$1", :"$2"}}]}])
    |> Enum.filter(fn {key, _} -> is_binary(key) and byte_size(key) == 16 end)
  end

  # Where is `agent` (an id or a name) as far as this host knows.
  def locate(host, agent) do
    {name, _} = host.ref

    case Tartarus.AgentTable.lookup(agent) do
      {:ok, pid, ^name} -> {:here, pid, agent}
      _ -> locate_elsewhere(host, agent)
    end
  end

  # Not resident here: arriving, or gone on (a forwarding pointer). An arriving agent
  # registers before it drops its `arriving` entry (and the forwarding pointer of its
  # previous visit), and a departing one writes its pointer before it leaves the table: a
  # reader that missed it in the table and then found neither entry looks in the table and
  # here once more. (An agent that hops at every arrival can come and go between two of the
  # reader's looks: then the pointer it left is there now.)
  defp locate_elsewhere(host, agent, again \\ true) do
    with [] <- :ets.lookup(host.ledger, {:arriving, agent}),
         [] <- pointer(host, agent) do
      if again, do: just_arrived(host, agent), else: locate_by_name(host, agent)
    else
      [{_, pid}] -> {:arriving, pid}
      [{_, dest, _, _, _}] -> {:moved, dest}
    end
  end

  # A forwarding pointer (not a hand-off record, which is kept under the same key).
  defp pointer(host, agent) do
    case :ets.lookup(host.ledger, {:fwd, agent}) do
      [{_, _, _, _, _}] = found -> found
      _ -> []
    end
  end

  defp just_arrived(host, agent) do
    {name, _} = host.ref

    case Tartarus.AgentTable.lookup(agent) do
      {:ok, pid, ^name} -> {:here, pid, agent}
      _ -> locate_elsewhere(host, agent, false)
    end
  end

  defp locate_by_name(host, agent) do
    # A select with the name as a constant: a name such as :_ or :"$1" is not a pattern.
    spec = [
      {{{:agent, :"$1"}, :"$2", :"$3", :_}, [{:"=:=", :"$3", {:const, agent}}],
       [{{:"$1", :"$2"}}]}
    ]

    case :ets.select(host.ledger, spec, 1) do
      {[{pid, id} | _], _} -> {:here, pid, id}
      _ -> :not_found
    end
  end
end
