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
  #   {:fwd, id | name}           {_, dest_host, at_us, {mig, copy}, notify}
  #                                                          forwarding pointer (and the record
  #                                                          of a committed migration)
  #   {:migrating, id}            {_, mig}                   a hand-off in progress (source)
  #   {:arriving, id}             {_, pid}                   a paused copy (destination)
  #   {:decision, mig}            {_, {:committed, copy} | :aborted} (a committed move's:
  #                                                          only until the forwarding pointer
  #                                                          is written)
  #   {:count, name}              {_, n}                     e.g. :dropped (unexpected messages)
  #   :resident, :visits, :hop_seq, {:count, name}           counters
  #   {:hop, slot}                {_, hop_us}                ring of recent hop times

  @slots 1024

  def neighbours(%{ledger: l}) do
    case :ets.lookup(l, :neighbours) do
      [{_, ns}] -> ns
      [] -> []
    end
  end

  def link(%{ledger: l}, dest) do
    case :ets.lookup(l, {:link, dest}) do
      [{_, props}] -> props
      [] -> nil
    end
  end

  def register_resident(host, env, pid) do
    {name, _node} = host.ref

    case Tartarus.AgentTable.register(env.id, pid, name, env.name, env.module) do
      :ok ->
        :ets.insert(host.ledger, {{:agent, pid}, env.id, env.name, env.module})
        :ets.delete(host.ledger, {:fwd, env.id})
        if env.name, do: :ets.delete(host.ledger, {:fwd, env.name})
        :ets.update_counter(host.ledger, :resident, 1)
        :ets.update_counter(host.ledger, :visits, 1)
        :ok

      {:error, _} = error ->
        error
    end
  end

  def forget_resident(host, pid) do
    case :ets.take(host.ledger, {:agent, pid}) do
      [{_, id, _, _}] ->
        Tartarus.AgentTable.unregister(id, pid)
        :ets.update_counter(host.ledger, :resident, -1)
        true

      [] ->
        false
    end
  end

  def begin_handoff(host, id, mig), do: :ets.insert(host.ledger, {{:migrating, id}, mig})
  def end_handoff(host, id), do: :ets.delete(host.ledger, {:migrating, id})

  # The source agent's decision. Returns false if the migration was decided otherwise.
  def decide(host, mig, decision), do: :ets.insert_new(host.ledger, {{:decision, mig}, decision})

  # The agent committed migration `mig` (copy `copy`) to `dest`: leave a forwarding pointer
  # (which also records the commit for a destination that asks, see decision/4) and stop
  # being resident. `notify` (a GenServer from, or nil) is who waits for the move to finish:
  # a destination that learns of the commit by asking (the commit message was lost) answers it.
  def depart(host, id, name, dest, mig, copy, notify) do
    now = System.system_time(:microsecond)
    :ets.insert(host.ledger, {{:fwd, id}, dest, now, {mig, copy}, notify})
    if name, do: :ets.insert(host.ledger, {{:fwd, name}, dest, now, {mig, copy}, nil})
    forget_resident(host, self())
    end_handoff(host, id)
    # The forwarding pointer now stands for the decision.
    :ets.delete(host.ledger, {:decision, mig})
  end

  # The answer to a paused copy `copy` of migration `mig` of agent `id` that asks this
  # (source) host: Tartarus.Migration.Protocol.answer/4 over what the ledger holds.
  def decision(host, mig, id, copy) do
    decision =
      case :ets.lookup(host.ledger, {:decision, mig}) do
        [{_, d}] -> d
        [] -> nil
      end

    pointer =
      case :ets.lookup(host.ledger, {:fwd, id}) do
        [{_, _dest, _at, {m, c}, notify}] -> {m, c, notify}
        _ -> nil
      end

    Tartarus.Migration.Protocol.answer(
      %{decision: decision, pointer: pointer},
      mig,
      copy,
      host.incarnation
    )
  end

  def count(%{ledger: l}, name),
    do: :ets.update_counter(l, {:count, name}, 1, {{:count, name}, 0})

  # After a crash of agent `id`: abort its pending hand-off if there is one. True if the agent
  # is still ours to restart, false if it had committed a migration (it lives elsewhere).
  def abort_pending(host, id) do
    case :ets.take(host.ledger, {:migrating, id}) do
      [{_, mig}] ->
        decide(host, mig, :aborted) or
          :ets.lookup(host.ledger, {:decision, mig}) == [{{:decision, mig}, :aborted}]

      [] ->
        true
    end
  end

  def record_hop(host, hop_us) do
    seq = :ets.update_counter(host.ledger, :hop_seq, 1)
    :ets.insert(host.ledger, {{:hop, rem(seq, @slots)}, hop_us})
  end

  def hop_times(%{ledger: l}) do
    :ets.select(l, [{{{:hop, :_}, :"$1"}, [], [:"$1"]}])
  end

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

  # Drops forwarding pointers written before `cutoff_us` (system time).
  def sweep_pointers(%{ledger: l}, cutoff_us) do
    :ets.select_delete(l, [{{{:fwd, :_}, :_, :"$1", :_, :_}, [{:<, :"$1", cutoff_us}], [true]}])
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

  defp locate_elsewhere(host, agent) do
    case :ets.lookup(host.ledger, {:arriving, agent}) do
      [{_, pid}] ->
        {:arriving, pid}

      [] ->
        case :ets.lookup(host.ledger, {:fwd, agent}) do
          [{_, dest, _, _, _}] -> {:moved, dest}
          [] -> just_arrived(host, agent)
        end
    end
  end

  # An arriving agent registers before it drops its `arriving` entry (and the forwarding
  # pointer of its previous visit): a reader that missed it in the table and then found
  # neither entry looks again.
  defp just_arrived(host, agent) do
    {name, _} = host.ref

    case Tartarus.AgentTable.lookup(agent) do
      {:ok, pid, ^name} -> {:here, pid, agent}
      _ -> locate_by_name(host, agent)
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
