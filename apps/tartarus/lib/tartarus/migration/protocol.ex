defmodule Tartarus.Migration.Protocol do
  @moduledoc """
  The hand-off protocol of a migration (move or clone), as pure functions: its messages
  (their validators are `Tartarus.Wire`'s) and the three parties' state machines written as
  `(state, event) -> {state, actions}`, one action per effect. The processes that run it
  (`Tartarus.Migration.Source` for the source, `Tartarus.Host.Arrivals` for admission,
  `Tartarus.Migration.Arrival` for the in-doubt copy, `Tartarus.Host.Parked` in the host's
  server) only turn messages into events; `Tartarus.Migration.Executor` carries out the
  actions through them. The model-checked property
  `Tartarus.Migration.ProtocolModelTest` drives these same functions over a network that
  drops, duplicates, delays, reorders and replays messages, with crashes and partitions.

  ## Parties

    * **S**, the source: the agent's own process, for one attempt (`source/6`,
      `source_step/2`). It writes the decision.
    * **H**, the destination's admission: a process spawned on the destination's node for
      each prepare (`Tartarus.Host.Arrivals`; by the node's door, `Tartarus.Host.ArrivalDoor`,
      for a source on another node), not the host's server; it admits or refuses
      (`destination/1`, `destination_step/2`) and, admitted, becomes the paused copy **A**
      and answers `prepared` (the host's server adopts it, asynchronously).
    * **A**, the paused (in-doubt) copy at the destination (`Tartarus.Migration.CopyProtocol`):
      runs nothing until it learns the decision, then becomes the agent.
    * **Hs**, the source host's server: answers decision queries (`answer/3`), takes
      acknowledgements and keeps parked copies (`Tartarus.Migration.HostProtocol`).

  ## Messages

      S  -> H   {:"$tartarus_prepare", s_pid, mig, src, src_pid, kind, env, manifest, code}
                                                        the argument of H's process, spawned
                                                        on the destination's node
      H  -> S   {:"$tartarus_need", mig, [module]}        modules H lacks; S resends with code
      H  -> S   {:"$tartarus_prepared", mig, copy, a_pid} A exists, paused, journaled
      H  -> S   {:"$tartarus_refused", mig, reason}       nothing was created
      S  -> A   {:"$tartarus_commit", mig, copy, notify, handover}
                                                        A becomes the agent; `handover` (a
                                                        move's) carries the messages S took
                                                        and had not handled, see below
      A  -> Hs  {:"$tartarus_decision?", mig, id, copy, a_pid}
      Hs -> A   {:"$tartarus_decision", mig, copy, :committed | {:committed, notify} | :aborted | :unknown}
      A  -> Hs  {:"$tartarus_acks", [{mig, id, copy}]}         A runs: Hs may forget the decision
                                                             (A's host batches them, lazily)

  `mig` is `{source_incarnation, ref}`, unique per attempt. `copy` is a token H makes for
  the one paused copy it creates for `mig`, unique across H's runs (16 bytes; it survives
  H's restart through the journal). It names a copy; it authenticates nobody.

  ## Decision rule

  While S's attempt is undecided, Hs's ledger holds a hand-off record of `mig` (written
  before `prepare` leaves, removed only after the decision, by S, or by Hs once S's process
  is dead). The only decision ever written is a commit: `{:committed, copy}`, naming the one
  copy S chose, written once (insert-if-absent) before `commit` leaves. An abort is the
  removal of the hand-off record with no commit written: nothing is stored for it. After a
  committed move the agent's forwarding pointer (which names `{mig, copy}`) stands for the
  decision. Hs answers a query for `(mig, copy)`, reading in this order:

    1. a hand-off record of `mig`: unknown (S has not decided yet); A asks again later;
    2. a decision or forwarding pointer names `mig` and this `copy`: committed;
    3. anything else: aborted. Either S aborted, or it committed another copy, or the
       record of its commit is gone, which happens only once nothing can still need it:
       the committed copy acknowledged it (`ack`), or the agent came back (a pointer is
       deleted when its agent arrives again), or Hs restarted (with persistence journaled
       commits are reloaded, so a missing one never committed; without, the agent died
       with that run).

  A starts only on a `commit` naming its `(mig, copy)` or a committed answer for it. Once
  it runs it acknowledges (`ack`) to Hs, which then drops a clone's decision (a move's is
  already replaced by the pointer) and marks the pointer acknowledged: it no longer stands
  for a decision, only for the agent's whereabouts, and `forward_ttl` may sweep it. Nothing
  that stands for an undecided or unacknowledged decision is ever removed by a timer.

  ## Guarantees and what each rests on

    * **At most one running copy.** Per `mig` at most one copy is committed, because the
      decision is written once and names the copy; S stops itself (or, for a clone, the
      clone has a new id) in the same step that sends `commit`. A replayed or duplicated
      `prepare` either meets H's memory of `mig` (H answers again with the same copy while
      it is paused, and refuses it once the copy started or was aborted) or,
      once that bounded memory forgot it (`seen_max`) or H restarted, creates a copy with a
      new token, which no decision names: it is told aborted. Replayed `commit`s and
      answers name a token only the first copy holds. Safety never rests on H's memory
      (the model checks it with a memory of one migration).
    * **Every commit survives a restart (with persistence).** S journals `{:decision, mig,
      id, copy}` for moves and clones before `commit` leaves; H journals each in-doubt copy
      under `{mig, copy}` before `prepared` leaves, so a second copy of one migration never
      replaces the first's record.
    * **A decision never changes.** A commit is insert-if-absent by the only writer (S), an
      abort is the absence of a commit after the hand-off record is gone (S is then done
      or dead: nobody writes a commit later). Hs reads the hand-off record first: S writes
      its decision before removing the record, and a move's pointer before dropping the
      decision, so a reader never sees "nothing" while a commit is on its way. Records of
      commits are removed only when no copy can still need them (above).
    * **Bounded records.** Aborts store nothing; a clone's commit is freed by its `ack`; a
      move's is its forwarding pointer, sweepable (`forward_ttl`) once acknowledged; the
      journal records `{:acked, mig}` so compaction drops the commit.
    * **No sealed field is forged.** With security on, the sending host's seal covers the
      envelope, the manifest, `mig`, `kind`, `src`, and both reply-to pids (`seal_fields/1`).
    * **Bounded cost of a stranger's prepares.** Paused copies count against admission
      (`max_resident_agents`), and a paused copy stashes at most `stash_max` messages (the
      rest are dropped and counted; their senders time out).
    * **In doubt, never a guess.** A copy whose source does not answer keeps asking, with a
      back-off capped at `max_ask_interval`; it never starts or drops itself on a timer. It
      is dropped only on an `:aborted` answer (or a host kill), started only on a committed
      one. After `park_after` queries it parks: its process (and stash) goes, its record
      stays with the host (and in the journal), which asks the source on its behalf at a
      low rate and revives or drops it only on an answer (`CopyProtocol.parked/1`). A
      source that never returns leaves a row — unreachable but recorded, counted by
      admission — never a duplicate.
  """

  alias Tartarus.Migration.Messages

  @typedoc "A migration id: the source host's incarnation and a unique reference."
  @type mig :: term()
  @typedoc "The token of one paused copy."
  @type copy_token :: term()
  @typedoc "An action for the executing process."
  @type action :: tuple() | atom()

  # -- source -----------------------------------------------------------------------

  @doc """
  The source's state for one attempt: migration `mig` of kind `kind` to host pid `dest`,
  `notify` the caller waiting for the outcome (or nil), `agent` the agent's id and `out`
  the id of what leaves (the agent's for a move, the clone's for a clone). It begins on
  the event `:begin`.
  """
  @spec source(mig(), :move | :clone, term(), term(), binary(), binary()) :: map()
  def source(mig, kind, dest, notify, agent, out) do
    %{
      mig: mig,
      kind: kind,
      dest: dest,
      notify: notify,
      agent: agent,
      out: out,
      phase: :idle,
      code: :none
    }
  end

  @doc """
  One step of the source: every effect is an action of its own, carried out in the order
  given (`Tartarus.Migration.Executor`); an action with a result answers with an event.

  Events: `:begin`, `{:prepared, mig, copy, pid}`, `{:need, mig, mods}`,
  `{:refused, mig, reason}`, `:timeout`, `{:down, reason}`, `{:decided, boolean}` (the
  result of `:decide`), `{:code, {:ok, code} | {:error, reason}}` (of `:fetch_code`).

  Actions: `{:begin_handoff, mig}` (the hand-off record: undecided for whoever asks),
  `:watch` (the destination), `:send_prepare`, `{:settle, {:prepared, pid} | :failed}`
  (stop watching), `{:decide, mig, copy}` (a clone's commit, insert-if-absent: answers
  `{:decided, boolean}`), `{:journal, record}`, `{:pointer_put, mig, copy, notify}` (a
  move's forwarding pointer: it replaces the hand-off record and is the decision),
  `:leave` (the resident tables), `{:committed, kind, mig, copy}` (the event of it),
  `{:end_handoff, mig}` (the hand-off record goes), `{:hand_over, pid, commit}` (a move's
  commit, sent with the messages the agent took and had not handled), `{:send, pid, msg}`,
  `{:fetch_code, mods}`, `{:resend, code}`, `{:done, {:committed, copy, pid} | {:failed,
  reason}}` (the last).

      iex> alias Tartarus.Migration.Protocol, as: P
      iex> s = P.source(:m, :move, :h, nil, "a", "a")
      iex> {s, acts} = P.source_step(s, :begin)
      iex> acts
      [{:begin_handoff, :m}, :watch, :send_prepare]
      iex> {_s, acts} = P.source_step(s, {:prepared, :m, :c, :a})
      iex> acts
      [{:settle, {:prepared, :a}}, {:journal, {:decision, :m, "a", :c}}, {:journal, {:forget, "a"}}, {:pointer_put, :m, :c, nil}, :leave, {:committed, :move, :m, :c}, {:hand_over, :a, {:"$tartarus_commit", :m, :c, nil, nil}}, {:done, {:committed, :c, :a}}]
  """
  @spec source_step(map(), term()) :: {map(), [action()]}
  def source_step(%{phase: :idle, mig: mig} = s, :begin),
    do: {%{s | phase: :preparing}, [{:begin_handoff, mig}, :watch, :send_prepare]}

  # A move: durable first (a restarted host must neither lose the commit nor restore the
  # agent), then the pointer, which is the decision, then the agent leaves, then the commit
  # leaves with what the agent held. Its hand-off record is gone with the pointer.
  def source_step(%{phase: :preparing, mig: mig, kind: :move} = s, {:prepared, mig, copy, pid}) do
    %{agent: id, notify: notify} = s

    {%{s | phase: {:committed, copy, pid}},
     [
       {:settle, {:prepared, pid}},
       {:journal, {:decision, mig, id, copy}},
       {:journal, {:forget, id}},
       {:pointer_put, mig, copy, notify},
       :leave,
       {:committed, :move, mig, copy},
       {:hand_over, pid, Messages.commit(mig, copy, notify)},
       {:done, {:committed, copy, pid}}
     ]}
  end

  # A clone: its commit is written (insert-if-absent) while the hand-off record stands.
  def source_step(%{phase: :preparing, mig: mig} = s, {:prepared, mig, copy, pid}),
    do:
      {%{s | phase: {:deciding, copy, pid}}, [{:settle, {:prepared, pid}}, {:decide, mig, copy}]}

  def source_step(%{phase: {:deciding, copy, pid}, mig: mig} = s, {:decided, true}) do
    {%{s | phase: {:committed, copy, pid}},
     [
       {:journal, {:decision, mig, s.out, copy}},
       {:committed, s.kind, mig, copy},
       {:end_handoff, mig},
       {:send, pid, Messages.commit(mig, copy, s.notify)},
       {:done, {:committed, copy, pid}}
     ]}
  end

  # A commit was already written (never happens: S is the only writer; kept total).
  def source_step(%{phase: {:deciding, _, _}} = s, {:decided, false}),
    do: {%{s | phase: :failed}, [{:end_handoff, s.mig}, {:done, {:failed, :aborted}}]}

  def source_step(%{phase: :preparing, mig: mig} = s, {:refused, mig, reason}),
    do: abort(s, reason)

  def source_step(%{phase: :preparing, mig: mig, code: :none} = s, {:need, mig, mods}),
    do: {%{s | code: :fetching}, [{:fetch_code, mods}]}

  def source_step(%{phase: :preparing, mig: mig} = s, {:need, mig, mods}),
    do: abort(s, {:code_not_accepted, mods})

  def source_step(%{phase: :preparing, code: :fetching} = s, {:code, {:ok, code}}),
    do: {%{s | code: :sent}, [{:resend, code}]}

  def source_step(%{phase: :preparing, code: :fetching} = s, {:code, {:error, reason}}),
    do: abort(s, reason)

  def source_step(%{phase: :preparing} = s, :timeout), do: abort(s, :timeout)
  def source_step(%{phase: :preparing} = s, {:down, reason}), do: abort(s, {:host_down, reason})
  def source_step(s, _event), do: {s, []}

  # An abort writes nothing: the hand-off record goes, with no commit, before the agent goes
  # on at the source, so a copy that asks from then on learns it.
  defp abort(s, reason) do
    {%{s | phase: :failed},
     [{:settle, :failed}, {:end_handoff, s.mig}, {:done, {:failed, reason}}]}
  end

  @doc "True once the source's attempt has ended."
  @spec source_done?(map()) :: boolean()
  def source_done?(%{phase: phase}), do: phase == :failed or match?({:committed, _, _}, phase)

  # -- destination host: admission ----------------------------------------------------

  @doc """
  The admission state of a destination host. Options: `:seen_max`, how many migrations it
  remembers (default 10_000); `:store`, `{module, table}` to remember them in, `module`
  giving `seen_claim(table, mig)` (`{:ok, what}`; `:error`, and `mig` is
  claimed by this admission until `seen_put(table, mig, what, seen_max)` or
  `seen_release(table, mig)`; or `:busy`, another admission of `mig` runs: the prepare is
  dropped, that one answers). A host's is `{Tartarus.Ledger, ledger}`: off any process's
  heap, shared by the processes that admit prepares concurrently (one per prepare,
  `Tartarus.Host.Arrivals`), so one migration is never admitted twice at once, and kept
  across a restart of the host's server. Without it the memory is a map in the state (this
  module's tests and the model, which admit one prepare at a time).
  """
  @spec destination(keyword()) :: map()
  def destination(opts \\ []) do
    seen_max = Keyword.get(opts, :seen_max, 10_000)

    case Keyword.get(opts, :store) do
      nil -> %{seen: %{}, order: :queue.new(), seen_max: seen_max}
      {module, table} when is_atom(module) -> %{seen: {module, table}, seen_max: seen_max}
    end
  end

  @doc """
  One step of admission. Events: `{:prepare, fields}` (a well-formed prepare,
  `classify/1`), `{:checked, fields, :ok | {:need, mods} | {:error, reason}, copy}` (the
  outcome of a `:check` action, with a fresh copy token), `{:created, fields, copy, pid}`,
  `{:create_failed, fields, reason}`, `{:probed, fields, copy, pid, still_paused?}` (the
  outcome of a `:probe`). Actions: `{:check, fields}` (trust, size, code, capacity),
  `{:probe, fields, copy, pid}` (is that copy still paused?), `{:create, fields, copy}` (a
  paused copy; answer `:created`),
  `{:journal, {:in_doubt, mig, env, src, kind, copy}}`, `{:send, pid, msg}`,
  `{:refuse, fields, reason}`.

      iex> alias Tartarus.Migration.Protocol, as: P
      iex> p = %{mig: :m, s_pid: :s, env: :e, src: :x, kind: :move}
      iex> {d, [{:check, ^p}]} = P.destination_step(P.destination(), {:prepare, p})
      iex> {d, [{:create, ^p, :c}]} = P.destination_step(d, {:checked, p, :ok, :c})
      iex> {d, acts} = P.destination_step(d, {:created, p, :c, :a})
      iex> acts
      [{:journal, {:in_doubt, :m, :e, :x, :move, :c}}, {:send, :s, {:"$tartarus_prepared", :m, :c, :a}}]
      iex> {d, [{:probe, ^p, :c, :a}]} = P.destination_step(d, {:prepare, p})
      iex> P.destination_step(d, {:probed, p, :c, :a, true}) |> elem(1)
      [{:send, :s, {:"$tartarus_prepared", :m, :c, :a}}]
      iex> P.destination_step(d, {:probed, p, :c, :a, false}) |> elem(1) |> hd() |> elem(2)
      :duplicate
  """
  @spec destination_step(map(), term()) :: {map(), [action()]}
  def destination_step(d, {:prepare, p}) do
    case seen(d, p.mig) do
      # A duplicate (or a replay) of a prepare this host made a copy for: is it still paused?
      {:ok, {:copy, copy, pid}} -> {d, [{:probe, p, copy, pid}]}
      :error -> {d, [{:check, p}]}
      # Another admission of this migration is under way: it answers.
      :busy -> {d, []}
    end
  end

  # Still paused: the same answer again (the first may have been lost). Resolved (it started
  # or was aborted): a replay, refused.
  def destination_step(d, {:probed, p, copy, pid, true}),
    do: {d, [{:send, p.s_pid, Messages.prepared(p.mig, copy, pid)}]}

  def destination_step(d, {:probed, p, _copy, _pid, false}), do: {d, [{:refuse, p, :duplicate}]}

  def destination_step(d, {:checked, p, :ok, copy}), do: {d, [{:create, p, copy}]}

  def destination_step(d, {:checked, p, {:need, mods}, _copy}),
    do: {release(d, p.mig), [{:send, p.s_pid, Messages.need(p.mig, mods)}]}

  # A refusal is not remembered: a forged prepare naming a real migration must not make the
  # real one refused. (Nothing was created; checking again costs only the check.)
  def destination_step(d, {:checked, p, {:error, reason}, _copy}),
    do: {release(d, p.mig), [{:refuse, p, reason}]}

  # The in-doubt copy is durable before `prepared` leaves.
  def destination_step(d, {:created, p, copy, pid}) do
    {remember(d, p.mig, {:copy, copy, pid}),
     [
       {:journal, {:in_doubt, p.mig, p.env, p.src, p.kind, copy}},
       {:send, p.s_pid, Messages.prepared(p.mig, copy, pid)}
     ]}
  end

  def destination_step(d, {:create_failed, p, reason}),
    do: {release(d, p.mig), [{:refuse, p, reason}]}

  def destination_step(d, _event), do: {d, []}

  @doc """
  Admission's memory of a paused copy restored from the journal (the host restarted).
  """
  @spec restore_seen(map(), mig(), copy_token(), term()) :: map()
  def restore_seen(d, mig, copy, pid), do: remember(d, mig, {:copy, copy, pid})

  # Bounded: the oldest migration is forgotten first. Forgetting is safe (a replay then
  # makes a copy with a new token, which no decision names); memory only spares the work.
  defp seen(%{seen: {module, table}}, mig), do: module.seen_claim(table, mig)
  defp seen(%{seen: seen}, mig), do: Map.fetch(seen, mig)

  # A claim that made no copy ends (a map claims nothing).
  defp release(%{seen: {module, table}} = d, mig) do
    :ok = module.seen_release(table, mig)
    d
  end

  defp release(d, _mig), do: d

  defp remember(%{seen: {module, table}} = d, mig, what) do
    :ok = module.seen_put(table, mig, what, d.seen_max)
    d
  end

  defp remember(d, mig, what) do
    if Map.has_key?(d.seen, mig) do
      %{d | seen: Map.put(d.seen, mig, what)}
    else
      d = %{d | seen: Map.put(d.seen, mig, what), order: :queue.in(mig, d.order)}

      if map_size(d.seen) > d.seen_max do
        {{:value, old}, order} = :queue.out(d.order)
        %{d | seen: Map.delete(d.seen, old), order: order}
      else
        d
      end
    end
  end

  # -- source host: decision queries -------------------------------------------------

  @doc """
  The source host's answer to a query for `(mig, copy)`, from what its ledger holds, read
  in this order: `handoff?` (a hand-off record of `mig` exists), `decision` (the commit of
  `mig`, or nil) and `pointer` (the agent's forwarding pointer as `{mig, copy, notify}`, or
  anything else).

      iex> alias Tartarus.Migration.Protocol, as: P
      iex> P.answer(%{handoff?: true, decision: nil, pointer: nil}, :m, :c)
      :unknown
      iex> P.answer(%{handoff?: false, decision: {:committed, :c}, pointer: nil}, :m, :c)
      :committed
      iex> P.answer(%{handoff?: false, decision: nil, pointer: {:m, :c, :n}}, :m, :c)
      {:committed, :n}
      iex> P.answer(%{handoff?: false, decision: nil, pointer: {:m, :c, :n}}, :m, :other)
      :aborted
      iex> P.answer(%{handoff?: false, decision: nil, pointer: nil}, :m, :c)
      :aborted
  """
  @spec answer(map(), mig(), copy_token()) ::
          :committed | {:committed, term()} | :aborted | :unknown
  def answer(%{handoff?: true}, _mig, _copy), do: :unknown

  def answer(%{decision: decision, pointer: pointer}, mig, copy) do
    case {decision, pointer} do
      {{:committed, ^copy}, _} -> :committed
      {_, {^mig, ^copy, notify}} -> {:committed, notify}
      _ -> :aborted
    end
  end
end
