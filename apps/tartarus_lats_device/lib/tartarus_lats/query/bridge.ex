defmodule TartarusLats.Query.Bridge do
  @moduledoc """
  The search a query agent makes around a break in a tag's chain of motion vectors
  (issue 28, item 5): it asks the nodes around the gap, ring by ring, for a stay of the
  tag that could continue the chain, moving between neighbours only.

  A break is where a chain of stays cannot be followed: a stay that "came from outside"
  on a node with no door, one that "left the building" from a node with no door, a
  vector with no matching vector on the other side (an MVF whose next node has no stay
  arriving then, an MVB whose previous node has no stay leaving then). What would mend
  it is a stay, near the break in time, whose own link on that side is missing too:

    * `{:left, t, to}` (walking back): a stay that ended within `window/0` seconds of
      `t` (when the stay after the break began) and went to nobody (`:infinity`,
      `:pending`) or to `to` (the node after the break);
    * `{:arrived, t, from}` (walking forward): a stay that began within `window/0`
      seconds of `t` (when the stay before the break ended) and came from nobody or
      from `from` (the node before the break).

  Ghost stays (`TartarusLats.Query.confirmed?/1`) and stays in `exclude` (already on
  the agent's path, `{node, arrived_at}`) never mend a break. The agent first looks on
  the node of the break itself (ring 0), then on its neighbours (ring 1), then on
  theirs (ring 2); it visits a whole ring before choosing, and takes the candidate
  nearest in time to `t` (then the lower ring, then node order). A bridge over ring 2
  skips the zone between (its node is not a neighbour of the break's): `through` lists
  the zones that can be, the neighbours of both. Zones change only between neighbours,
  so when there is one such zone the tag passed through it.

  The pieces are pure functions over a plain map that travels in the agent's state:
  `new/4`, `candidate/4` (the best stay on one node's table), `visit/5` (note a node's
  candidate and extend the ring), `next/1` (where to move next, or the choice).
  `TartarusLats.Query.Trace` uses them with `repair: true`.
  """

  alias TartarusLats.{MotionVectors, Query}

  @rings 2
  @window 30

  @typedoc "What would mend the break (see the moduledoc)."
  @type want ::
          {:left, number(), MotionVectors.node_name()}
          | {:arrived, number(), MotionVectors.node_name()}

  @typedoc "A search under way."
  @type t :: %{
          gap: MotionVectors.node_name(),
          gap_host: term(),
          want: want(),
          exclude: [{MotionVectors.node_name(), number()}],
          queue: [{MotionVectors.node_name(), [term()], non_neg_integer()}],
          seen: [MotionVectors.node_name()],
          trail: [term()],
          from_trail: [term()],
          plan: [{term(), [term()]}],
          around: [MotionVectors.node_name()],
          best: nil | found()
        }

  @typedoc """
  The stay chosen: on `node`, reached by `trail` (hosts from the gap's), `ring` rings
  from the gap; `through`: for a stay two rings away, the gap's neighbours that are its
  node's neighbours too (the zones the tag can have passed between them).
  """
  @type found :: %{
          dt: number(),
          ring: non_neg_integer(),
          node: MotionVectors.node_name(),
          trail: [term()],
          stay: MotionVectors.segment(),
          through: [MotionVectors.node_name()]
        }

  @doc "How far in time (seconds) from the break a mending stay may be."
  @spec window() :: pos_integer()
  def window, do: @window

  @doc "How many rings of neighbours around the break are asked."
  @spec rings() :: pos_integer()
  def rings, do: @rings

  @doc """
  A search around the break at `gap` (on host `gap_host`, whose neighbours are
  `neighbours`, `%{node => host}`) for a stay that meets `want`, never one of `exclude`.
  The agent is on the gap's node; call `visit/5` there first (ring 0).
  """
  @spec new(MotionVectors.node_name(), term(), want(), [{MotionVectors.node_name(), number()}]) ::
          t()
  def new(gap, gap_host, want, exclude) do
    %{
      gap: gap,
      gap_host: gap_host,
      want: want,
      exclude: exclude,
      queue: [{gap, [], 0}],
      seen: [gap],
      trail: [],
      from_trail: [],
      plan: [],
      around: [],
      best: nil
    }
  end

  @doc """
  The stay of `tag` in table `mv` (node `node`) that would mend the break best: the
  nearest in time among those that meet `want` (see the moduledoc), or `nil`.

      iex> tag = :t
      iex> mv = %TartarusLats.MotionVectors{node: :b, tags: %{t: [
      ...>   %{arrived_at: 50, from: :infinity, from_left_at: nil, left_at: nil, to: nil, to_arrived_at: nil},
      ...>   %{arrived_at: 10, from: :a, from_left_at: 9, left_at: 30, to: :infinity, to_arrived_at: nil}]}}
      iex> TartarusLats.Query.Bridge.candidate(mv, tag, {:left, 40, :c}, []).left_at
      30
      iex> TartarusLats.Query.Bridge.candidate(mv, tag, {:arrived, 45, :a}, []).arrived_at
      50
      iex> TartarusLats.Query.Bridge.candidate(mv, tag, {:left, 80, :c}, [])
      nil
  """
  @spec candidate(MotionVectors.t() | nil, term(), want(), [{MotionVectors.node_name(), number()}]) ::
          MotionVectors.segment() | nil
  def candidate(nil, _tag, _want, _exclude), do: nil

  def candidate(mv, tag, want, exclude) do
    mv
    |> MotionVectors.segments(tag)
    |> Enum.filter(&(Query.confirmed?(&1) and {mv.node, &1.arrived_at} not in exclude))
    |> Enum.filter(&mends?(&1, want))
    |> Enum.min_by(&distance(&1, want), fn -> nil end)
  end

  defp mends?(%{left_at: l, to: to}, {:left, t, next}) when is_number(l),
    do: abs(l - t) <= @window and to in [:infinity, :pending, next]

  defp mends?(%{arrived_at: a, from: from}, {:arrived, t, prev}),
    do: abs(a - t) <= @window and from in [:infinity, :pending, prev]

  defp mends?(_stay, _want), do: false

  defp distance(%{left_at: l}, {:left, t, _}), do: abs(l - t)
  defp distance(%{arrived_at: a}, {:arrived, t, _}), do: abs(a - t)

  @doc """
  Notes what the agent found on the node at the head of the queue (`node`, table `mv`,
  `neighbours`): its candidate, if better than the best so far, and, below the last
  ring, its neighbours not seen yet as the next ring.
  """
  @spec visit(t(), MotionVectors.node_name(), MotionVectors.t() | nil, map(), term()) :: t()
  def visit(%{queue: [{_n, path, depth} | rest]} = b, node, mv, neighbours, tag) do
    around = if depth == 0, do: Enum.sort(Map.keys(neighbours)), else: b.around

    best =
      case candidate(mv, tag, b.want, b.exclude) do
        nil ->
          b.best

        stay ->
          through =
            if depth == @rings,
              do: neighbours |> Map.keys() |> Enum.filter(&(&1 in around)) |> Enum.sort(),
              else: []

          mine = %{
            dt: distance(stay, b.want),
            ring: depth,
            node: node,
            trail: path,
            stay: stay,
            through: through
          }

          if b.best == nil or key(mine) < key(b.best), do: mine, else: b.best
      end

    ring =
      if depth < @rings,
        do:
          for({n, h} <- Enum.sort(neighbours), n not in b.seen, do: {n, path ++ [h], depth + 1}),
        else: []

    %{
      b
      | queue: rest ++ ring,
        seen: b.seen ++ Enum.map(ring, &elem(&1, 0)),
        best: best,
        around: around
    }
  end

  defp key(f), do: {f.dt, f.ring, f.node}

  @doc """
  After a move that failed: the agent is where it was before it, and the node at the
  head of the queue (or the one chosen) is given up.
  """
  @spec skip(t()) :: t()
  def skip(%{best: %{trail: path}, trail: path} = b),
    do: %{b | best: nil, plan: [], trail: b.from_trail}

  def skip(%{queue: [_ | rest]} = b), do: %{b | queue: rest, plan: [], trail: b.from_trail}
  def skip(b), do: %{b | plan: [], trail: b.from_trail}

  @doc """
  What to do next: `{:move, host, b}` (on the way to the next node to ask, or to the
  chosen one), `{:ask, b}` when the agent stands on the next node to ask (call
  `visit/5` there), `{:found, found, b}` when it stands on the node of the chosen stay
  (`t:found/0`), or `:none` when every node
  within `rings/0` was asked and none had a stay that mends the break.

  A ring is finished before a choice is made: once a candidate is known and the next
  node to ask is in a further ring (or none is left), the agent goes to the candidate.
  """
  @spec next(t()) ::
          {:move, term(), t()}
          | {:ask, t()}
          | {:found, found(), t()}
          | :none
  def next(%{plan: [{host, trail} | plan]} = b),
    do: {:move, host, %{b | plan: plan, trail: trail, from_trail: b.trail}}

  def next(%{best: %{ring: depth, trail: path} = found} = b) do
    ring_done =
      case b.queue do
        [] -> true
        [{_, _, d} | _] -> d > depth
      end

    cond do
      not ring_done -> go_to_head(b)
      b.trail == path -> {:found, found, b}
      true -> plan_to(b, path) |> next()
    end
  end

  def next(%{queue: []}), do: :none
  def next(b), do: go_to_head(b)

  # The head of the queue is asked where the agent stands once the plan to it is done.
  defp go_to_head(%{queue: [{_n, path, _d} | _]} = b) do
    if b.trail == path, do: {:ask, b}, else: plan_to(b, path) |> next()
  end

  # The agent moves between neighbours only: back along its trail to the longest common
  # prefix with `path`, then on along `path`.
  defp plan_to(b, path) do
    k = common_prefix(b.trail, path)
    anchors = [b.gap_host | b.trail]
    back = for i <- (length(b.trail) - 1)..k//-1, do: {Enum.at(anchors, i), Enum.take(b.trail, i)}
    forward = for j <- (k + 1)..length(path)//1, do: {Enum.at(path, j - 1), Enum.take(path, j)}
    %{b | plan: back ++ forward}
  end

  defp common_prefix([x | a], [x | b]), do: 1 + common_prefix(a, b)
  defp common_prefix(_a, _b), do: 0
end
