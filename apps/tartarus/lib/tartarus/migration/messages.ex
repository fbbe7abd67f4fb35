defmodule Tartarus.Migration.Messages do
  @moduledoc """
  The messages of the hand-off protocol (`Tartarus.Migration.Protocol` is their
  specification): their constructors, `classify/1` (a message as the protocol's event) and
  the checks of their fields. Each is a tuple tagged with an atom that no agent message
  uses, so a process tells them from everything else by their first element.
  """

  alias Tartarus.Migration.Protocol

  @doc "The `prepare` message."
  @spec prepare(pid(), Protocol.mig(), term(), pid(), :move | :clone, term(), list(), list()) ::
          tuple()
  def prepare(s_pid, mig, src, src_pid, kind, env, manifest, code),
    do: {:"$tartarus_prepare", s_pid, mig, src, src_pid, kind, env, manifest, code}

  @doc "A `prepare` sent again, now with code."
  @spec with_code(tuple(), list()) :: tuple()
  def with_code(prepare, code), do: put_elem(prepare, 8, code)

  @doc "The `need` message."
  @spec need(Protocol.mig(), [module()]) :: tuple()
  def need(mig, mods), do: {:"$tartarus_need", mig, mods}

  @doc "The `prepared` message."
  @spec prepared(Protocol.mig(), Protocol.copy_token(), pid()) :: tuple()
  def prepared(mig, copy, pid), do: {:"$tartarus_prepared", mig, copy, pid}

  @doc "The `refused` message."
  @spec refused(Protocol.mig(), term()) :: tuple()
  def refused(mig, reason), do: {:"$tartarus_refused", mig, reason}

  @doc """
  The `commit` message. A move's carries the source process's hand-over of messages,
  `{msgs, seen}` (`Tartarus.Migration.Inbox.handover/2`): a hop is three messages,
  `prepare`, `prepared`, `commit`.
  """
  @spec commit(Protocol.mig(), Protocol.copy_token(), term(), term()) :: tuple()
  def commit(mig, copy, notify, handover \\ nil),
    do: {:"$tartarus_commit", mig, copy, notify, handover}

  @doc "The decision query of a paused copy."
  @spec decision_query(Protocol.mig(), binary(), Protocol.copy_token(), pid()) :: tuple()
  def decision_query(mig, id, copy, pid), do: {:"$tartarus_decision?", mig, id, copy, pid}

  @doc "Acknowledgements of committed copies that run, each `{mig, id, copy}`."
  @spec acks([{Protocol.mig(), binary(), Protocol.copy_token()}]) :: tuple()
  def acks(list), do: {:"$tartarus_acks", list}

  @doc "The answer to a decision query."
  @spec decision(Protocol.mig(), Protocol.copy_token(), term()) :: tuple()
  def decision(mig, copy, d), do: {:"$tartarus_decision", mig, copy, d}

  @doc """
  What a message is to the protocol: `{:prepare, fields}`, `{:prepared, mig, copy, pid}`,
  `{:need, mig, mods}`, `{:refused, mig, reason}`, `{:commit, mig, copy, notify}`,
  `{:query, mig, id, copy, pid}`, `{:decision, mig, copy, d}`, `{:acks, [{mig, id, copy}]}`,
  or `:other`. Total.

      iex> Tartarus.Migration.Messages.classify(:hello)
      :other
  """
  @spec classify(term()) :: tuple() | :other
  def classify({:"$tartarus_prepare", s_pid, mig, src, src_pid, kind, env, manifest, code}),
    do:
      {:prepare,
       %{
         s_pid: s_pid,
         mig: mig,
         src: src,
         src_pid: src_pid,
         kind: kind,
         env: env,
         manifest: manifest,
         code: code
       }}

  def classify({:"$tartarus_prepared", mig, copy, pid}), do: {:prepared, mig, copy, pid}
  def classify({:"$tartarus_need", mig, mods}), do: {:need, mig, mods}
  def classify({:"$tartarus_refused", mig, reason}), do: {:refused, mig, reason}

  def classify({:"$tartarus_commit", mig, copy, notify, _handover}),
    do: {:commit, mig, copy, notify}

  def classify({:"$tartarus_decision?", mig, id, copy, pid}), do: {:query, mig, id, copy, pid}
  def classify({:"$tartarus_decision", mig, copy, d}), do: {:decision, mig, copy, d}
  def classify({:"$tartarus_acks", list}), do: {:acks, list}
  def classify(_), do: :other

  @doc """
  True for a message of the hand-off protocol (any of the above, well-formed or not).

      iex> Tartarus.Migration.Messages.protocol_message?({:"$tartarus_need", 1, []})
      true
  """
  @spec protocol_message?(term()) :: boolean()
  def protocol_message?(msg) when is_tuple(msg) and tuple_size(msg) > 0,
    do:
      elem(msg, 0) in [
        :"$tartarus_prepare",
        :"$tartarus_need",
        :"$tartarus_prepared",
        :"$tartarus_refused",
        :"$tartarus_commit",
        :"$tartarus_decision?",
        :"$tartarus_decision",
        :"$tartarus_acks"
      ]

  def protocol_message?(_), do: false

  @doc """
  The fields of a `prepare` a receiver acts on besides the envelope: what the sending
  host's seal covers (with the manifest and the envelope).
  """
  @spec seal_fields(map()) :: tuple()
  def seal_fields(p), do: {p.mig, p.kind, p.src, p.s_pid, p.src_pid}

  @doc "True for a migration id as hosts make them."
  @spec migration_id?(term()) :: boolean()
  def migration_id?({incarnation, ref}), do: is_binary(incarnation) and is_reference(ref)
  def migration_id?(_), do: false

  @doc "True for a copy token as hosts make them."
  @spec copy_token?(term()) :: boolean()
  def copy_token?(t), do: is_binary(t) and byte_size(t) == 16
end
