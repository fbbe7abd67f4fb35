defmodule Tartarus.Migration.HostProtocol do
  @moduledoc """
  A host's own part of the hand-off protocol (`Tartarus.Migration.Protocol` is the
  specification), as a pure function `event -> actions`: as a source host it answers
  decision queries and takes acknowledgements; as a destination host it keeps the records
  of its parked copies, asks their sources and revives or drops them on an answer. What it
  reads and writes is the host's ledger and journal, so it keeps no state of its own.
  `Tartarus.Migration.Executor.host_event/3` carries the actions out
  (`Tartarus.Host.Parked` live, in the host's server; the model check in memory).

  Events: `{:query, mig, id, copy, to}`; `{:acks, [{mig, id, copy}]}`; `{:park, mig, copy,
  env, src, kind, from}` (a paused copy, `from` its call, hands over its record);
  `:ask_parked` (the host's timer); `{:decision, mig, copy, d}` (a source's answer about a
  parked copy); and the results of actions: `{:read, mig, copy, to, view}`, `{:parked,
  from, :first | :more | :not_here}`, `{:asking, records}`, `{:fetched, mig, copy, d,
  {:ok, {env, src, kind}} | :error}`, `{:revived, mig, copy, d, {:ok, pid} | :error, env,
  src, kind}`.

  Actions: `{:read, mig, id, copy, to}` (the ledger's view for `Protocol.answer/3`: answers
  `{:read, ...}`), `{:send, to, msg}`, `{:acknowledge, mig, id, copy}`, `{:journal, record}`,
  `{:park, mig, copy, env, src, kind, from}` (the record, if `from` is the copy arriving
  here: answers `{:parked, ...}`), `{:reply, from, answer}`, `:arm_ask` (the timer),
  `:read_parked` (answers `{:asking, records}`), `{:ask, src, query}`, `{:fetch_parked, mig,
  copy, d}` (answers `{:fetched, ...}`), `:dropped` (counted), `{:unpark, mig, copy}`,
  `{:revive, mig, copy, d, env, src, kind}` (a paused copy again: answers `{:revived, ...}`),
  `{:arriving, id, pid}`.

  A revived copy takes its parked record itself as it starts (`CopyProtocol.new/5`'s
  `:claim`), so the host forgets nothing before the copy runs: a host server that dies
  between reviving and the copy's start leaves the record to be asked about again (by the
  server started in its place), and a second copy revived from it then finds it taken and
  stops.

      iex> alias Tartarus.Migration.HostProtocol, as: H
      iex> H.step({:read, :m, :c, :a, %{handoff?: false, decision: nil, pointer: {:m, :c, nil}}})
      [{:send, :a, {:"$tartarus_decision", :m, :c, {:committed, nil}}}]
      iex> H.step({:acks, [{:m, "id", :c}]})
      [{:acknowledge, :m, "id", :c}, {:journal, {:acked, :m}}]
  """

  alias Tartarus.Migration.{CopyProtocol, Messages, Protocol}

  @doc "The host's actions for `event` (see the moduledoc)."
  @spec step(term()) :: [tuple() | atom()]
  def step({:query, mig, id, copy, to}), do: [{:read, mig, id, copy, to}]

  def step({:read, mig, copy, to, view}),
    do: [{:send, to, Messages.decision(mig, copy, Protocol.answer(view, mig, copy))}]

  # The commit of `mig` to `copy` is no longer needed (its copy runs).
  def step({:acks, acks}),
    do:
      Enum.flat_map(acks, fn {mig, id, copy} ->
        [{:acknowledge, mig, id, copy}, {:journal, {:acked, mig}}]
      end)

  def step({:park, mig, copy, env, src, kind, from}),
    do: [{:park, mig, copy, env, src, kind, from}]

  def step({:parked, from, :first}), do: [:arm_ask, {:reply, from, :ok}]
  def step({:parked, from, :more}), do: [{:reply, from, :ok}]
  def step({:parked, from, :not_here}), do: [{:reply, from, {:error, :not_paused_here}}]

  # A timer that only asks: it never decides anything.
  def step(:ask_parked), do: [:read_parked]
  def step({:asking, []}), do: []

  def step({:asking, records}) do
    asks =
      for {mig, copy, env, src, kind} <- records,
          do: {:ask, src, {mig, Tartarus.Ledger.query_id(env, kind), copy}}

    asks ++ [:arm_ask]
  end

  def step({:decision, mig, copy, d}), do: [{:fetch_parked, mig, copy, d}]
  def step({:fetched, _mig, _copy, _d, :error}), do: [:dropped]

  # Revived or dropped only on an answer that says so: parking never duplicates an agent.
  def step({:fetched, mig, copy, d, {:ok, {env, src, kind}}}) do
    case CopyProtocol.parked(d) do
      :keep -> []
      :drop -> [{:unpark, mig, copy}, {:journal, {:resolved, mig, copy}}]
      :revive -> [{:revive, mig, copy, d, env, src, kind}]
    end
  end

  def step({:revived, mig, copy, d, {:ok, pid}, env, _src, _kind}),
    do: [{:arriving, env.id, pid}, {:send, pid, Messages.decision(mig, copy, d)}]

  # Not revived (the host is stopping, or full): the record stays for the next answer.
  def step({:revived, _mig, _copy, _d, :error, _env, _src, _kind}), do: []

  @doc """
  What a host does, as it starts again, with what its journal restored
  (`Tartarus.Host.Persistence.restored/1`: its agents and in-doubt copies; its decisions
  are its ledger's from the start), in this order: `{:not_started, envs}`, the agents and
  copies whose code this node cannot run (`runnable?` false: their records are kept for a
  start with it installed); `{:start, env}` for each agent, started resident from its
  checkpoint (it registers itself: an id resident already is not started twice);
  `:await_started` (until they have registered, so the host comes back with them
  findable); then `{:pause, mig, copy, env, src, kind}` for each in-doubt copy: paused
  again with no source process to wait for (it asks its source), remembered by admission
  (`Tartarus.Migration.Protocol.restore_seen/4`). `Tartarus.Host.Agents.restore/1` carries
  it out, and the model check's hosts restart by it.

      iex> alias Tartarus.Migration.HostProtocol, as: H
      iex> H.restore([%{id: "a"}], [{:m, %{id: "b"}, :src, :move, :c}], fn _ -> true end)
      [{:not_started, []}, {:start, %{id: "a"}}, :await_started, {:pause, :m, :c, %{id: "b"}, :src, :move}]
  """
  @spec restore([map()], [tuple()], (map() -> boolean())) :: [tuple() | atom()]
  def restore(agents, in_doubt, runnable?) do
    {agents, unrunnable} = Enum.split_with(agents, runnable?)
    {in_doubt, unrunnable_copies} = Enum.split_with(in_doubt, &runnable?.(elem(&1, 1)))

    [{:not_started, unrunnable ++ Enum.map(unrunnable_copies, &elem(&1, 1))}] ++
      Enum.map(agents, &{:start, &1}) ++
      [:await_started] ++
      for {mig, env, src, kind, copy} <- in_doubt, do: {:pause, mig, copy, env, src, kind}
  end
end
