defmodule TartarusLats.Query do
  @moduledoc """
  What a query looks at on one node, as pure functions: the query agents
  (`TartarusLats.Query.WhereAmI`, `TartarusLats.Query.WhereIs`,
  `TartarusLats.Query.Trace`) call them on the motion-vector table they find
  in the host store of the node they are on, and the cloud of the
  centralized design (`TartarusLats.Cloud`) calls the same functions over
  its mirror of every node's table, so both designs decide alike.

  ## Answers

    * Where am I / Where is X: `{:in_zone, node}` (the tag's MVF at `node` is
      the presence indicator `{node, node}`), `:left_building` (the last MVF
      points to INFINITY), `:not_found` (no node has a trace: the tag never
      came in; only after the whole network was searched), `{:in_transit,
      node}` (the last node's handshake is still undecided).
    * Trace(X): `{:ok, %{path: [%{node, arrived_at, left_at}], entry, status}}`
      (the shape of `TartarusLats.MotionVectors.trace/3`: `entry` is
      `:infinity` when the walk back reached the stay where X came in, `:gap` when
      that stay "came from outside" on a node with no door to the outside (a lost
      hand-over: what came before is missing, and the answer is not complete),
      `status` is `:present`, `:exited`, `:in_transit` or `:broken`), or
      `:not_found`.

  ## Ghost stays (presence confirmation)

  Radio noise can make a node see, for a few seconds, a tag that never left
  a neighbour's zone. Such a stay has no neighbour on either side: it came
  from INFINITY and went to INFINITY, and it is short. A query that read it
  would conclude "left the building" (or start a trace there). So a stay is
  *confirmed* unless it is isolated (`from` and `to` both `:infinity`) and
  shorter than `ghost_seconds/0`; queries skip unconfirmed stays and go on
  searching, as if the node had no trace. (A real visit that neither comes
  from nor goes to a neighbour is a person who walked in at an entrance and
  out again within a few seconds without reaching any other zone.)
  """

  alias TartarusLats.MotionVectors

  @ghost_seconds 10

  @typedoc "A node (zone) name."
  @type node_name :: MotionVectors.node_name()

  @typedoc "Answer of Where am I / Where is X."
  @type where_answer ::
          {:in_zone, node_name()} | :left_building | :not_found | {:in_transit, node_name()}

  @typedoc "Answer of Trace(X)."
  @type trace_answer :: {:ok, MotionVectors.trace()} | :not_found

  @typedoc "What to do next at a node while following a tag's vectors."
  @type step ::
          {:found, node_name()}
          | {:next, node_name(), number()}
          | :left_building
          | :in_transit
          | :no_trace

  @doc "Stays shorter than this (seconds) with no neighbour on either side are ghosts."
  @spec ghost_seconds() :: pos_integer()
  def ghost_seconds, do: @ghost_seconds

  @doc """
  True if a stay is confirmed (not a ghost; see the moduledoc).

      iex> TartarusLats.Query.confirmed?(%{from: :infinity, to: :infinity, arrived_at: 10, left_at: 14})
      false
      iex> TartarusLats.Query.confirmed?(%{from: :p2, to: :infinity, arrived_at: 10, left_at: 14})
      true
  """
  @spec confirmed?(MotionVectors.segment()) :: boolean()
  def confirmed?(%{from: :infinity, to: :infinity, arrived_at: a, left_at: l})
      when is_number(l),
      do: l - a >= @ghost_seconds

  def confirmed?(_stay), do: true

  @doc "The latest confirmed stay of `tag` in table `mv`, or `nil`."
  @spec latest(MotionVectors.t() | nil, TartarusLats.Beacon.tag_id()) ::
          MotionVectors.segment() | nil
  def latest(nil, _tag), do: nil
  def latest(mv, tag), do: mv |> MotionVectors.segments(tag) |> Enum.find(&confirmed?/1)

  @doc """
  One step of following a tag's MVF at the node whose table is `mv`.

  `arrived_at` selects the stay to follow (the one the previous node's MVF
  pointed to); `nil` means the latest confirmed stay (the first node with a
  trace). Returns `{:found, here}` when the tag is here now, `{:next, node,
  arrived_at}` to go on to `node`, `:left_building`, `:in_transit`, or
  `:no_trace` when this node knows nothing of the tag.
  """
  @spec follow(MotionVectors.t() | nil, TartarusLats.Beacon.tag_id(), number() | nil) :: step()
  def follow(mv, tag, arrived_at \\ nil)
  def follow(nil, _tag, _arrived_at), do: :no_trace

  def follow(mv, tag, arrived_at) do
    stay =
      if arrived_at,
        do: MotionVectors.arrival(mv, tag, arrived_at) || latest(mv, tag),
        else: latest(mv, tag)

    follow_stay(mv, tag, stay, 64)
  end

  defp follow_stay(_mv, _tag, nil, _n), do: :no_trace
  defp follow_stay(_mv, _tag, _stay, 0), do: :in_transit
  defp follow_stay(mv, _tag, %{to: nil}, _n), do: {:found, mv.node}
  defp follow_stay(_mv, _tag, %{to: :infinity}, _n), do: :left_building
  defp follow_stay(_mv, _tag, %{to: :pending}, _n), do: :in_transit

  # A loop here -> here (the tag stepped out of range and came back): follow it locally.
  defp follow_stay(%{node: here} = mv, tag, %{to: here, to_arrived_at: t}, n),
    do: follow_stay(mv, tag, MotionVectors.arrival(mv, tag, t), n - 1)

  defp follow_stay(_mv, _tag, %{to: node, to_arrived_at: t}, _n), do: {:next, node, t}

  @doc """
  Answers Where is X over a whole map of tables (the centralized design):
  start at `start`, search the nodes in order for a first trace, then follow
  MVF links.
  """
  @spec where_is(%{node_name() => MotionVectors.t()}, node_name(), TartarusLats.Beacon.tag_id()) ::
          where_answer()
  def where_is(tables, start, tag) do
    first =
      [start | tables |> Map.keys() |> Enum.sort()]
      |> Enum.find(&(follow(tables[&1], tag) != :no_trace))

    if first, do: chase(tables, first, tag, nil, map_size(tables) * 4), else: :not_found
  end

  defp chase(_tables, node, _tag, _t, 0), do: {:in_transit, node}

  defp chase(tables, node, tag, t, n) do
    case follow(tables[node], tag, t) do
      {:found, here} -> {:in_zone, here}
      {:next, next, t} -> chase(tables, next, tag, t, n - 1)
      :left_building -> :left_building
      :in_transit -> {:in_transit, node}
      :no_trace -> {:in_transit, node}
    end
  end

  @doc """
  Answers Trace(X) over a whole map of tables (the centralized design): the
  visit through the latest confirmed stay of the first node (from `start`,
  then in node order) that has one.
  """
  @spec trace(%{node_name() => MotionVectors.t()}, node_name(), TartarusLats.Beacon.tag_id()) ::
          trace_answer()
  def trace(tables, start, tag) do
    first =
      [start | tables |> Map.keys() |> Enum.sort()]
      |> Enum.find(&(latest(tables[&1], tag) != nil))

    case first do
      nil ->
        :not_found

      node ->
        stay = latest(tables[node], tag)
        # Drop the newer (ghost) stays so that MotionVectors.trace/3 starts at `stay`.
        mv = tables[node]
        kept = Enum.drop_while(MotionVectors.segments(mv, tag), &(&1 != stay))
        tables = Map.put(tables, node, %{mv | tags: Map.put(mv.tags, tag, kept)})
        MotionVectors.trace(tables, node, tag)
    end
  end

  @doc """
  Merges consecutive stays at the same node of a path (a tag that stepped
  out of range and came back) into one.

      iex> TartarusLats.Query.merge([%{node: :a, arrived_at: 1, left_at: 5}, %{node: :a, arrived_at: 6, left_at: 9}, %{node: :b, arrived_at: 8, left_at: nil}])
      [%{node: :a, arrived_at: 1, left_at: 9}, %{node: :b, arrived_at: 8, left_at: nil}]
  """
  @spec merge([%{node: node_name(), arrived_at: number(), left_at: number() | nil}]) :: [map()]
  def merge(path) do
    path
    |> Enum.chunk_by(& &1.node)
    |> Enum.map(fn [first | _] = run -> %{first | left_at: List.last(run).left_at} end)
  end
end
