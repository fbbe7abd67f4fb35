defmodule TartarusLats.Query.WhereIs do
  @moduledoc """
  Where is X? (thesis §3.3.5, query 2) as an ordinary mobile agent.

  Released on any host with `%{tag: tag}` (see `TartarusLats.query/4`), it
  reads the motion vectors of X in the host store of the node it is on
  (`TartarusLats.DatabaseAgent` publishes them) and:

    * MVF `{here, here}` (X is here): answers `{:in_zone, here}`;
    * MVF `{here, next}`: migrates to `next` and looks at the stay the vector
      points to;
    * MVF `{here, INFINITY}`: answers `:left_building`;
    * no trace of X: migrates conscientiously (thesis Appendix .1) until a
      node has one, or answers `:not_found` once every node it has heard of
      (its own and its neighbours' names, gathered on the way) was visited.

  Ghost stays are skipped (see `TartarusLats.Query`). The agent contacts the
  cloud from every node where it finds data of the tag (`cloud: :per_node`,
  the default: the thesis's scenario 2) or once, from the node where it
  found the answer (`cloud: :per_query`), and returns `%{answer, hops,
  route, answered_at, cloud_contacts, per_node_contacts,
  per_query_contacts, elapsed_us, ...}` to its owner.

  With `repair: true` a dead end (`:left_building`, in transit) is first checked with the
  nodes around it: the agent visits the neighbours of the node where the chain ended, and
  theirs, for a stay of X that began after the one that ended there; the first found
  bridges the gap and the agent follows the chain on from it (`bridges` in the result:
  `%{from, to, since, arrived_at}` each). Off by default.

  Arguments: `:tag` (required), `:label`, `:report` (contact the cloud,
  default true), `:cloud`, `:max_hops` (default 500), `:repair` (default false).
  """
  use Tartarus.Agent, ships: [TartarusLats.Query, TartarusLats.Query.Walk]

  alias TartarusLats.Query
  alias TartarusLats.Query.Walk

  @rings 2
  @max_bridges 3

  @impl true
  def init(args) do
    args
    |> Walk.new(:where_is)
    |> Map.merge(%{at: nil, repair: Map.get(args, :repair, false), bridge: nil, bridges: []})
    |> step()
  end

  @impl true
  def handle_arrival(_ctx, %{bridge: %{plan: [_ | _]}} = s), do: travel(s)

  def handle_arrival(_ctx, s), do: step(s)

  # A failed move while bridging: that node is out of reach; try the next one from where
  # the agent is.
  @impl true
  def handle_move_failed(_dest, _reason, _ctx, %{bridge: %{queue: [_ | rest]} = b} = s),
    do: next_bridge(%{s | bridge: %{b | queue: rest, plan: []}})

  def handle_move_failed(dest, _reason, _ctx, s), do: Walk.move_failed(s, dest, &step/1)

  @doc false
  def step(s) do
    {node, mv, neighbours, s} = Walk.look(s)

    if Map.get(s, :bridge),
      do: bridge_step(node, mv, neighbours, s),
      else: decide(node, mv, neighbours, s)
  end

  defp decide(node, mv, neighbours, s) do
    case Query.follow(mv, s.tag, s.at) do
      {:found, here} ->
        finish({:in_zone, here}, s)

      {:next, next, t} ->
        Walk.go(neighbours, next, %{s | at: t}, fn ->
          dead_end({:in_transit, node}, node, mv, neighbours, s)
        end)

      :left_building ->
        dead_end(:left_building, node, mv, neighbours, s)

      :in_transit ->
        dead_end({:in_transit, node}, node, mv, neighbours, s)

      :no_trace when s.at != nil ->
        dead_end({:in_transit, node}, node, mv, neighbours, s)

      :no_trace ->
        Walk.search(s, :not_found)
    end
  end

  # The chain ends here (the tag left from here to nobody, or is between here and a next
  # zone that does not know it). Without `:repair` that is the answer. With it, the agent
  # first asks the nodes around the gap, up to 2 rings of neighbours (`@rings`), for a stay
  # of the tag that began after the one that ends here: the first it finds (ring by ring,
  # in node order) bridges the gap and the agent follows the chain on from there; none,
  # and the answer stands. At most 3 bridges a query (`@max_bridges`).
  defp dead_end(answer, node, mv, neighbours, s) do
    stay = Query.latest(mv, s.tag)

    if Map.get(s, :repair, false) and stay != nil and length(s.bridges) < @max_bridges do
      since = Enum.max([stay.arrived_at | Enum.map(s.bridges, & &1.since)])

      bridge = %{
        gap: node,
        gap_host: Tartarus.Agent.host(),
        since: since,
        answer: answer,
        # {node, hosts from the gap to it, ring}
        queue: for({n, h} <- Enum.sort(neighbours), do: {n, [h], 1}),
        seen: [node | Map.keys(neighbours)],
        # hosts from the gap to where the agent is, and the moves planned
        trail: [],
        plan: []
      }

      next_bridge(%{s | bridge: bridge})
    else
      finish(answer, s)
    end
  end

  # The agent moves between neighbours only: to reach the next node of the queue it walks
  # back along its trail to the longest common prefix with that node's path, then on.
  defp next_bridge(%{bridge: %{queue: []} = b} = s), do: finish(b.answer, %{s | bridge: nil})

  defp next_bridge(%{bridge: %{queue: [{_n, path, _d} | _]} = b} = s) do
    k = common_prefix(b.trail, path)
    anchors = [b.gap_host | b.trail]
    back = for i <- (length(b.trail) - 1)..k//-1, do: {Enum.at(anchors, i), Enum.take(b.trail, i)}

    forward = for j <- (k + 1)..length(path)//1, do: {Enum.at(path, j - 1), Enum.take(path, j)}

    travel(%{s | bridge: %{b | plan: back ++ forward}})
  end

  defp travel(%{bridge: %{plan: [{host, trail} | plan]} = b} = s),
    do: {:move, host, %{s | bridge: %{b | plan: plan, trail: trail}}}

  defp travel(%{bridge: %{plan: []}} = s), do: step(s)

  defp common_prefix([x | a], [x | b]), do: 1 + common_prefix(a, b)
  defp common_prefix(_a, _b), do: 0

  defp bridge_step(node, mv, neighbours, %{bridge: b} = s) do
    [{_n, path, depth} | rest] = b.queue
    stay = Query.latest(mv, s.tag)

    if stay != nil and stay.arrived_at > b.since do
      bridged = %{from: b.gap, to: node, since: b.since, arrived_at: stay.arrived_at}
      decide(node, mv, neighbours, %{s | bridge: nil, at: nil, bridges: s.bridges ++ [bridged]})
    else
      ring =
        if depth < @rings,
          do:
            for(
              {n, h} <- Enum.sort(neighbours),
              n not in b.seen,
              do: {n, path ++ [h], depth + 1}
            ),
          else: []

      seen = b.seen ++ Enum.map(ring, &elem(&1, 0))
      next_bridge(%{s | bridge: %{b | queue: rest ++ ring, seen: seen}})
    end
  end

  defp finish(answer, s) do
    {:return, result, s} = Walk.finish(answer, s, true)
    {:return, Map.put(result, :bridges, Map.get(s, :bridges, [])), s}
  end
end
