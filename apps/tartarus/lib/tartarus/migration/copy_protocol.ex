defmodule Tartarus.Migration.CopyProtocol do
  @moduledoc """
  The paused (in-doubt) copy's part of the hand-off protocol (`Tartarus.Migration.Protocol`
  is the specification), as pure functions `(state, event) -> {state, actions}`: it runs
  nothing until it learns its migration's decision, then becomes the agent through one
  action per effect, in the order the guarantees need. `Tartarus.Migration.Executor` carries
  the actions out (`Tartarus.Migration.Arrival` live, the model check in memory).

  Becoming the agent: `{:become, handover}` (its own state: the messages handed over and
  stashed, the envelope's hop; nothing outside the process), `:register` (resident here;
  answers `{:registered, :ok | {:error, reason}}`), then `:put_snapshot` (what a crash restarts
  from), `:checkpoint` (the journal's record of the agent, before anything tells the source
  it runs), `:drop_arriving`, `{:resolve, mig, copy}` (the journal's in-doubt record ends:
  after the checkpoint, so a restart finds the one or the other), `{:ack, src, mig, copy}`
  (the source host may forget its commit: after both journal writes), `:arrived` (its
  event and hop time), `{:reply, notify, kind}` (whoever waits for the move, last) and
  `:started`, which ends it.
  """

  alias Tartarus.Migration.Messages

  @doc """
  The state of a paused copy `copy` of migration `mig` from source host `src`. Options:
  `:stash_max` (messages kept while paused, default 1_000), `:ask_after` (first query, in
  ms, default 1_000), `:max_ask_interval` (cap of the back-off, default 30_000),
  `:park_after` (queries without a decisive answer before the copy parks, default 20:
  about eight minutes), `:src_pid` (the source agent's process when the prepare came from
  it: a move that learns its commit by asking waits for that process's commit, which
  carries the messages it held), `:claim` (true for a copy its host revived from a parked
  record: before it acts on a decision or a commit it takes that record, `{:claim, mig,
  copy}`, answered `{:claimed, taken?}`, and stops if another revived copy took it first;
  so a host whose server dies anywhere between reviving and forgetting the record neither
  loses the agent nor starts it twice).
  """
  @spec new(term(), term(), term(), :move | :clone, keyword()) :: map()
  def new(mig, copy, src, kind, opts \\ []) do
    %{
      mig: mig,
      copy: copy,
      src: src,
      kind: kind,
      src_pid: Keyword.get(opts, :src_pid),
      phase: :paused,
      notify: nil,
      stashed: 0,
      dropped: 0,
      asks: 0,
      stash_max: Keyword.get(opts, :stash_max, 1_000),
      ask_after: Keyword.get(opts, :ask_after, 1_000),
      max_ask_interval: Keyword.get(opts, :max_ask_interval, 30_000),
      park_after: Keyword.get(opts, :park_after, 20),
      claim: Keyword.get(opts, :claim, false),
      claiming: nil
    }
  end

  @doc """
  One step of a paused copy. Events: `{:commit, mig, copy, notify, handover}`, `:timeout`
  (its timer), `{:decision, mig, copy, d}`, `{:message, msg}` (anything else sent to it),
  `{:handover, handover}` (while it awaits the source's commit: the commit's, or nil once
  the source ended or its timer fired), `{:registered, result}`. Actions: those of the
  moduledoc (an aborted migration's copy: `{:resolve, mig, copy}`, then stops),
  `{:ask, src, mig, copy}`,
  `{:timer, ms}`, `{:stash, msg}`, `{:drop, msg}`, `{:await, src_pid}` (wait for the
  source's commit), `:park` (hand the record to the host, which keeps asking, `parked/1`,
  and stop), `{:stop, reason}`.

      iex> alias Tartarus.Migration.CopyProtocol, as: C
      iex> c = C.new(:m, :c, :src, :move)
      iex> C.step(c, {:commit, :m, :other, nil, nil}) |> elem(1)
      []
      iex> {c, acts} = C.step(c, {:commit, :m, :c, nil, nil})
      iex> acts
      [{:become, nil}, :register]
      iex> C.step(c, {:registered, :ok}) |> elem(1)
      [:put_snapshot, :checkpoint, :drop_arriving, {:resolve, :m, :c}, {:ack, :src, :m, :c}, :arrived, {:reply, nil, :move}, :started]

  A copy revived from a parked record takes that record first; the second of two revived
  from one record finds it taken and stops:

      iex> alias Tartarus.Migration.CopyProtocol, as: C
      iex> {c, acts} = C.step(C.new(:m, :c, :src, :move, claim: true), {:decision, :m, :c, :committed})
      iex> acts
      [{:claim, :m, :c}]
      iex> C.step(c, {:claimed, false}) |> elem(1)
      [{:stop, {:shutdown, :revived_elsewhere}}]
      iex> C.step(c, {:claimed, true}) |> elem(1)
      [{:become, nil}, :register]
  """
  @spec step(map(), term()) :: {map(), [tuple() | atom()]}
  # A revived copy takes its parked record before it acts on a decisive event.
  def step(%{mig: mig, copy: copy, phase: :paused, claim: true} = c, event)
      when elem(event, 0) in [:commit, :decision] and elem(event, 1) == mig and
             elem(event, 2) == copy do
    if decisive?(event),
      do: {%{c | phase: :claiming, claiming: event}, [{:claim, mig, copy}]},
      else: {c, []}
  end

  def step(%{phase: :claiming} = c, {:claimed, true}),
    do: step(%{c | phase: :paused, claim: false, claiming: nil}, c.claiming)

  def step(%{phase: :claiming} = c, {:claimed, false}),
    do: {%{c | phase: :stopped, claiming: nil}, [{:stop, {:shutdown, :revived_elsewhere}}]}

  def step(%{mig: mig, copy: copy, phase: :paused} = c, {:commit, mig, copy, notify, handover}),
    do: start(c, notify, handover)

  def step(%{asks: asks, park_after: n, phase: :paused} = c, :timeout) when asks >= n,
    do: {c, [:park]}

  def step(%{phase: :paused} = c, :timeout) do
    interval = min(c.ask_after * Integer.pow(2, min(c.asks, 16)), c.max_ask_interval)
    {%{c | asks: c.asks + 1}, [{:ask, c.src, c.mig, c.copy}, {:timer, interval}]}
  end

  def step(%{mig: mig, copy: copy, phase: :paused} = c, {:decision, mig, copy, d}) do
    case d do
      {:committed, notify} ->
        committed(c, notify)

      :committed ->
        committed(c, nil)

      :aborted ->
        {%{c | phase: :stopped}, [{:resolve, mig, copy}, {:stop, {:shutdown, :aborted}}]}

      _unknown ->
        {c, []}
    end
  end

  def step(%{phase: :paused} = c, {:message, msg}) do
    if c.stashed < c.stash_max,
      do: {%{c | stashed: c.stashed + 1}, [{:stash, msg}]},
      else: {%{c | dropped: c.dropped + 1}, [{:drop, msg}]}
  end

  def step(%{phase: :awaiting} = c, {:handover, handover}), do: start(c, c.notify, handover)

  def step(%{phase: :starting} = c, {:registered, :ok}) do
    %{mig: mig, copy: copy, src: src} = c

    {%{c | phase: :started},
     [
       :put_snapshot,
       :checkpoint,
       :drop_arriving,
       {:resolve, mig, copy},
       {:ack, src, mig, copy},
       :arrived,
       {:reply, c.notify, c.kind},
       :started
     ]}
  end

  def step(%{phase: :starting} = c, {:registered, {:error, reason}}),
    do: {%{c | phase: :stopped}, [{:stop, reason}]}

  def step(c, _event), do: {c, []}

  defp decisive?({:commit, _, _, _, _}), do: true

  defp decisive?({:decision, _, _, d}),
    do: match?({:committed, _}, d) or d in [:committed, :aborted]

  # A move that learnt its commit by asking while its source's process may live waits for
  # that process's commit (it carries the messages the source held): taking newer messages
  # first would break a sender's order and the memory of what was taken.
  defp committed(%{kind: :move, src_pid: pid} = c, notify) when pid != nil,
    do: {%{c | phase: :awaiting, notify: notify}, [{:await, pid}]}

  defp committed(c, notify), do: start(c, notify, nil)

  defp start(c, notify, handover),
    do: {%{c | phase: :starting, notify: notify}, [{:become, handover}, :register]}

  @doc """
  The event of the copy's timer: `:timeout`, or, while it awaits its source's commit,
  `{:handover, nil}` (it starts without it).
  """
  @spec timeout(map()) :: :timeout | {:handover, nil}
  def timeout(%{phase: :awaiting}), do: {:handover, nil}
  def timeout(_c), do: :timeout

  @doc """
  The event a message is for the copy `c`, or nil (a stray hand-off message of an earlier
  attempt, or, while it awaits its source's commit, anything but that commit: postponed).

      iex> c = Tartarus.Migration.CopyProtocol.new(:m, :c, :src, :move)
      iex> Tartarus.Migration.CopyProtocol.event(c, :hello)
      {:message, :hello}
  """
  @spec event(map(), term()) :: term() | nil
  def event(%{phase: :awaiting, mig: mig}, {:"$tartarus_commit", mig, _copy, _notify, handover}),
    do: {:handover, handover}

  def event(%{phase: :awaiting}, _msg), do: nil

  def event(_c, msg) do
    case Messages.classify(msg) do
      {:commit, mig, copy, notify} -> {:commit, mig, copy, notify, elem(msg, 4)}
      {:decision, _, _, _} = decision -> decision
      :other -> {:message, msg}
      _stray -> nil
    end
  end

  @doc """
  What a host does with a parked copy's record on an answer from its source: `:revive` (a
  paused copy again, which starts: committed), `:drop` (aborted), `:keep` (unknown: ask
  again later). A parked record is never dropped or revived otherwise, so parking cannot
  duplicate an agent; it only trades a waiting process for a row.

      iex> Tartarus.Migration.CopyProtocol.parked({:committed, nil})
      :revive
  """
  @spec parked(term()) :: :revive | :drop | :keep
  def parked(:committed), do: :revive
  def parked({:committed, _}), do: :revive
  def parked(:aborted), do: :drop
  def parked(_), do: :keep
end
