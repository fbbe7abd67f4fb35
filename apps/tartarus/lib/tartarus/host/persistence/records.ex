defmodule Tartarus.Host.Persistence.Records do
  @moduledoc false
  # The records of a host's journal (Tartarus.Host.Persistence writes them,
  # Tartarus.Host.Persistence.JournalFile frames and reads them) and their replay:
  #
  #   {:agent, id, env}                  agent arrived (or was created): its snapshot
  #   {:forget, id}                      agent stopped, or was killed
  #   {:in_doubt, mig, env, src, kind, copy}  this host prepared paused copy `copy` (destination)
  #   {:resolved, mig, copy}             that copy was committed or aborted
  #   {:decision, mig, id, copy}         this host committed migration mig of agent id to the
  #                                      paused copy `copy` (source)
  #   {:acked, mig}                      the committed copy of mig runs: its decision record
  #                                      is no longer needed (source)
  #   {:code, module, md5}               the binary of `module` a journaled agent needs is
  #                                      kept in code/<md5>.beam
  #                                      (Tartarus.Host.Persistence.ShippedCode)
  #
  # In-doubt copies are keyed by {mig, copy}: a second copy of one migration (a duplicated or
  # replayed prepare the host no longer remembered) must not replace the first's record.
  #
  # Replaying the journal in order (apply_record/2 folded from empty/0) gives the state to
  # restore; a `decision` or a later `agent` record supersedes earlier records about the same
  # agent, so a host that died between two writes restores nothing twice. records/1 gives a
  # state's live records back (what a compaction writes): the state's size, not the
  # journal's history.

  @doc false
  # Whether `term` is a journal record of a shape apply_record/2 knows.
  def record?({:agent, id, %{id: id}}) when is_binary(id), do: true
  def record?({:forget, id}) when is_binary(id), do: true

  def record?({:in_doubt, _mig, %{id: id}, _src, kind, _copy})
      when is_binary(id) and is_atom(kind),
      do: true

  def record?({:resolved, _mig, _copy}), do: true
  def record?({:acked, _mig}), do: true
  def record?({:decision, _mig, id, _copy}) when is_binary(id), do: true
  def record?({:code, mod, md5}) when is_atom(mod) and is_binary(md5), do: true
  def record?(_), do: false

  @doc false
  # The replayed state of an empty journal (the fold of apply_record/2 over the records;
  # the protocol model folds the same way).
  def empty, do: %{agents: %{}, in_doubt: %{}, decisions: %{}, code: %{}}

  @doc false
  def apply_record({:agent, id, env}, s),
    do: %{s | agents: Map.put(s.agents, id, env), in_doubt: drop_agent(s.in_doubt, id)}

  def apply_record({:forget, id}, s), do: %{s | agents: Map.delete(s.agents, id)}

  def apply_record({:in_doubt, mig, env, src, kind, copy}, s),
    do: %{s | in_doubt: Map.put(s.in_doubt, {mig, copy}, {env, src, kind})}

  def apply_record({:resolved, mig, copy}, s),
    do: %{s | in_doubt: Map.delete(s.in_doubt, {mig, copy})}

  def apply_record({:decision, mig, id, copy}, s) do
    # A move to this same host has its in-doubt copy here too: that one stays (it asks, finds
    # the decision and starts).
    %{
      s
      | agents: Map.delete(s.agents, id),
        in_doubt: drop_agent(s.in_doubt, id, mig),
        decisions: Map.put(s.decisions, mig, {id, copy})
    }
  end

  def apply_record({:acked, mig}, s), do: %{s | decisions: Map.delete(s.decisions, mig)}

  def apply_record({:code, mod, md5}, s),
    do: %{s | code: Map.put(Map.get(s, :code, %{}), mod, md5)}

  # A record of an unknown shape (JournalFile.read/1 sets such frames aside): skipped.
  def apply_record(_other, s), do: s

  defp drop_agent(in_doubt, id, keep \\ nil),
    do: Map.reject(in_doubt, fn {{mig, _copy}, {env, _, _}} -> env.id == id and mig != keep end)

  @doc false
  # The live records of a replayed state, in an order that replays to the same state.
  def records(s) do
    Enum.map(Map.get(s, :code, %{}), fn {mod, md5} -> {:code, mod, md5} end) ++
      Enum.map(s.decisions, fn {mig, {id, copy}} -> {:decision, mig, id, copy} end) ++
      Enum.map(s.in_doubt, fn {{mig, copy}, {env, src, kind}} ->
        {:in_doubt, mig, env, src, kind, copy}
      end) ++
      Enum.map(s.agents, fn {id, env} -> {:agent, id, env} end)
  end

  @doc false
  # The state with only the code records a live agent or in-doubt copy needs (the others
  # are dropped: the compaction of opening, Tartarus.Host.Persistence.open/2).
  def needed_code(s) do
    envs = Map.values(s.agents) ++ Enum.map(Map.values(s.in_doubt), &elem(&1, 0))
    needed = MapSet.new(Enum.flat_map(envs, &modules_of/1))
    %{s | code: Map.filter(Map.get(s, :code, %{}), fn {mod, _} -> mod in needed end)}
  end

  defp modules_of(env) do
    Tartarus.Envelope.modules(Tartarus.Envelope.upgrade(env))
  rescue
    _ -> []
  end

  @doc false
  # The state to restore in the shapes a host takes it: {agents, in_doubt as
  # [{mig, env, src, kind, copy}], decisions as [{mig, copy}]}.
  def restored(s) do
    # Envelopes an earlier version journaled take this version's shape.
    up = &Tartarus.Envelope.upgrade/1

    {Enum.map(Map.values(s.agents), up),
     Enum.map(s.in_doubt, fn {{mig, copy}, {env, src, kind}} ->
       {mig, up.(env), src, kind, copy}
     end), Enum.map(s.decisions, fn {mig, {_id, copy}} -> {mig, copy} end)}
  end
end
