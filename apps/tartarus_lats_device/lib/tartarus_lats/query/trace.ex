defmodule TartarusLats.Query.Trace do
  @moduledoc """
  Trace(X) (thesis §3.3.5, query 3; Algorithm 1; Appendix .2) as an ordinary
  mobile agent: the ordered list of zones X visited, with the time X entered
  and left each.

  Released on any host with `%{tag: tag}`:

    1. **search** - while the node it is on has no (confirmed) trace of X it
       migrates conscientiously; it answers `:not_found` once every node it
       has heard of was visited;
    2. at the first node `v` with a trace, if `v` is where X's path ends
       (MVF `{v, v}`: X is here, or `{v, INFINITY}`: X left from here), it
       **walks back** along MVB to the entry, pushing every stay on a stack:
       the stack is the path (Algorithm 1, first branch);
    3. otherwise (MVF `{v, w}`) it walks back along MVB to the entry (stacking
       the stays), returns along the stack to `v`, then **walks forward** along
       MVF to the last node, queueing every stay: stack then queue is the path
       (Algorithm 1's second branch; Appendix .2: fired at `e`, the agent goes
       to `d`, then follows `d -> e -> f -> i -> h`). Algorithm 1 re-reads the
       first part from the MVFs on the way forward; we return along the stack
       instead, because the MVB and MVF of one hand-over can disagree when a
       tag bounced at a zone boundary (the neighbour acknowledged after this
       node had already seen the tag come back), and the MVB walk is the one
       that already succeeded.

  Every hop of the walks follows a link between two stays (the timestamps
  of `TartarusLats.MotionVectors`), so a tag that visited a node several
  times is traced exactly. Consecutive stays at the same node are merged.

  The answer is `{:ok, %{path: [%{node, arrived_at, left_at}], entry,
  status}}` (as `TartarusLats.MotionVectors.trace/3`; `status` `:present`,
  `:exited`, `:in_transit`, or `:broken` if a link could not be followed) or
  `:not_found`. The agent contacts the cloud as `:cloud` says (see
  `TartarusLats.Query.WhereIs`) and returns the same map as
  `TartarusLats.Query.WhereIs`.

  ## Breaks, and bridging them (`repair: true`)

  The walk can meet a break in the chain: a stay that "came from outside" on a node
  with no door (`{:lats, :entrance}` false: a lost hand-over), a stay that "left the
  building" from a node with no door, an MVB whose previous node has no stay leaving
  then, an MVF whose next node has no stay arriving then. Every break is reported in
  the result's `breaks` (`%{node, kind: :entry | :exit | :back_link | :forward_link,
  at, bridged_to, ring, through}`: where, what, at what time) and an answer with a break is
  not complete. With `repair: true` the agent asks the nodes around the break for the
  tag's stays in that time window (`TartarusLats.Query.Bridge`: the node itself, its
  neighbours, theirs) and bridges it with the stay nearest in time that has the same
  link missing on its side; `bridged_to` names its node and `ring` how far it was. A
  bridge over two rings skips a zone: when exactly one zone is a neighbour of both ends
  (`through`), the tag passed through it unseen (zones change only between neighbours)
  and it goes on the path, dated between the two stays; otherwise the zone is unknown.
  The answer stays complete only when every break was bridged with no zone unknown. At
  most 6 bridges a query.
  Walking back to the first node after the bridges, the agent retraces its own moves
  (between neighbours only).

  Arguments: `:tag` (required), `:label`, `:report`, `:cloud`, `:max_hops`, `:repair`
  (default false).
  """
  use Tartarus.Agent,
    ships: [TartarusLats.Query, TartarusLats.Query.Walk, TartarusLats.Query.Bridge]

  alias Tartarus.Agent, as: A
  alias TartarusLats.{MotionVectors, Query}
  alias TartarusLats.Query.{Bridge, Walk}

  @max_bridges 6

  @impl true
  def init(args) do
    s =
      args
      |> Walk.new(:trace)
      |> Map.merge(%{
        phase: :search,
        branch: nil,
        at: nil,
        path: [],
        found: nil,
        back_hosts: [],
        repair: Map.get(args, :repair, false),
        bridge: nil,
        resume: nil,
        breaks: []
      })

    step(s)
  end

  @impl true
  def handle_arrival(_ctx, %{resume: {_, _}} = s), do: resume(s)
  def handle_arrival(_ctx, s), do: step(s)

  # A node around a break that cannot be reached is given up (the answer names it).
  @impl true
  def handle_move_failed(dest, _reason, _ctx, %{bridge: %{} = b} = s) do
    s = Walk.unreachable(s, dest)
    step(%{s | bridge: %{b | search: Bridge.skip(b.search)}})
  end

  def handle_move_failed(dest, _reason, _ctx, %{phase: :search} = s),
    do: Walk.move_failed(s, dest, &step/1)

  def handle_move_failed(dest, _reason, _ctx, s),
    do: Walk.move_failed(s, dest, &done(:broken, &1))

  defp step(s) do
    {node, mv, neighbours, s} = Walk.look(s)

    if s.bridge,
      do: bridging(s, node, mv, neighbours),
      else: act(s.phase, node, mv, neighbours, s)
  end

  defp act(:search, node, mv, neighbours, s) do
    case Query.latest(mv, s.tag) do
      nil ->
        Walk.search(s, :not_found)

      stay ->
        # The path ends here (X is here, or left the building from here) unless it left
        # from a node with no door: a break, to bridge forward when repairing.
        exit_break? = stay.to == :infinity and not entrance?()
        s = if exit_break? and not s.repair, do: add_break(s, node, :exit, stay.left_at), else: s
        last? = stay.to == nil or (stay.to == :infinity and not (exit_break? and s.repair))
        branch = if last?, do: :last, else: :middle
        s = %{s | branch: branch, phase: :back, found: {node, stay}}
        back(node, stay, neighbours, s)
    end
  end

  defp act(:back, node, mv, neighbours, s) do
    case mv && MotionVectors.departure(mv, s.tag, s.at) do
      %{} = stay ->
        back(node, stay, neighbours, s)

      _ ->
        # An MVB with no matching MVF: the stay after it came from here, but no stay here
        # ended then.
        [after_break | _] = s.path
        want = {:left, after_break.arrived_at, after_break.node}
        break(:back_link, node, s.at, want, neighbours, s, :broken)
    end
  end

  defp act(:return, node, _mv, neighbours, s), do: return(node, neighbours, s)

  defp act(:forward, node, mv, neighbours, s) do
    case mv && MotionVectors.arrival(mv, s.tag, s.at) do
      %{} = stay ->
        forward(node, stay, neighbours, %{s | path: s.path ++ [entry(node, stay)]})

      _ ->
        # An MVF with no matching MVB: the stay before it went here, no stay here began then.
        before_break = List.last(s.path)
        want = {:arrived, before_break.left_at, before_break.node}
        break(:forward_link, node, s.at, want, neighbours, s, :broken)
    end
  end

  # Walking back along MVB, pushing every stay on the stack (the path so far).
  defp back(node, stay, neighbours, s) do
    s = %{s | path: [entry(node, stay) | s.path]}

    case stay.from do
      :infinity ->
        if entrance?() do
          entered(node, neighbours, Map.put(s, :entry, :infinity))
        else
          # Came "from outside" where there is no door: a lost hand-over.
          want = {:left, stay.arrived_at, node}

          break(:entry, node, stay.arrived_at, want, neighbours, s, :gap)
        end

      :pending ->
        entered(node, neighbours, Map.put(s, :entry, :pending))

      ^node ->
        # A loop here -> here: the previous stay is on this node too.
        local(
          MotionVectors.departure(mv(), s.tag, stay.from_left_at),
          s,
          &back(node, &1, neighbours, &2)
        )

      prev ->
        s = %{s | at: stay.from_left_at, back_hosts: [A.host() | s.back_hosts]}
        Walk.go(neighbours, prev, s, fn -> done(:broken, s) end)
    end
  end

  # The walk back reached the entry (or gave up there): done, or back to the first node
  # with a trace and forward from there.
  defp entered(node, neighbours, s) do
    {_, found} = s.found

    if s.branch == :last,
      do: done(status(found), s),
      else: return(node, neighbours, %{s | phase: :return})
  end

  # Back to the first node with a trace, retracing the agent's moves, then forward.
  defp return(node, neighbours, %{back_hosts: []} = s) do
    {_, found} = s.found
    forward(node, found, neighbours, %{s | phase: :forward})
  end

  defp return(_node, _neighbours, %{back_hosts: [host | rest]} = s),
    do: {:move, host, %{s | back_hosts: rest}}

  # Walking forward along MVF from `stay` (already on the path), queueing every stay.
  defp forward(node, stay, neighbours, s) do
    case stay.to do
      next when next in [nil, :pending] ->
        done(status(stay), s)

      :infinity ->
        if entrance?() do
          done(:exited, s)
        else
          # "Left the building" where there is no door: a lost hand-over.
          want = {:arrived, stay.left_at, node}
          break(:exit, node, stay.left_at, want, neighbours, s, :exited)
        end

      ^node ->
        local(MotionVectors.arrival(mv(), s.tag, stay.to_arrived_at), s, fn next, s ->
          forward(node, next, neighbours, %{s | path: s.path ++ [entry(node, next)]})
        end)

      next ->
        Walk.go(neighbours, next, %{s | at: stay.to_arrived_at}, fn -> done(:broken, s) end)
    end
  end

  # A break at `node` (the agent is on it): noted; without repair (or past the bridges
  # allowed) `otherwise` decides the answer (`give_up/5`); with it, the search around the
  # break begins.
  defp break(kind, node, at, want, neighbours, s, otherwise) do
    bridged = Enum.count(s.breaks, & &1.bridged_to)

    if s.repair and bridged < @max_bridges do
      exclude = Enum.map(s.path, &{&1.node, &1.arrived_at})
      search = Bridge.new(node, A.host(), want, exclude)
      b = %{search: search, kind: kind, node: node, at: at, phase: s.phase, otherwise: otherwise}
      bridging(%{s | bridge: b}, node, mv(), neighbours)
    else
      give_up(otherwise, node, neighbours, add_break(s, node, kind, at))
    end
  end

  # One step of the search around a break: ask the node the agent stands on, move on,
  # take the chosen stay and go on walking from it, or give up.
  defp bridging(%{bridge: %{search: search} = b} = s, node, mv, neighbours) do
    case Bridge.next(search) do
      {:ask, search} ->
        search = Bridge.visit(search, node, mv, neighbours, s.tag)
        bridging(%{s | bridge: %{b | search: search}}, node, mv, neighbours)

      {:move, host, search} ->
        {:move, host, %{s | bridge: %{b | search: search}}}

      {:found, %{node: ^node, stay: stay} = found, _search} ->
        # Two rings away with one zone between (a neighbour of both): the tag passed
        # through it, unseen (that node was down or missed it); it goes on the path.
        through = with [v] <- found.through, do: v, else: (_ -> nil)
        brk = %{brk(b.node, b.kind, b.at, node, found.ring) | through: through}
        s = %{s | bridge: nil, breaks: s.breaks ++ [brk]}

        case b.phase do
          :back ->
            # The way back to the first node with a trace passes the gap again.
            [gap_stay | _] = s.path
            s = %{s | back_hosts: way_back(b.search.gap_host, found.trail) ++ s.back_hosts}
            s = if through, do: %{s | path: [unseen(through, stay, gap_stay) | s.path]}, else: s
            back(node, stay, neighbours, s)

          :forward ->
            gap_stay = List.last(s.path)
            between = if through, do: [unseen(through, gap_stay, stay)], else: []
            forward(node, stay, neighbours, %{s | path: s.path ++ between ++ [entry(node, stay)]})
        end

      :none ->
        # No stay mends it: the break stands, and the walk goes on from the gap's node.
        s = add_break(%{s | bridge: nil}, b.node, b.kind, b.at)

        case way_back(b.search.gap_host, b.search.trail) do
          [] -> give_up(b.otherwise, node, neighbours, s)
          [host | hosts] -> {:move, host, %{s | resume: {b.otherwise, hosts}}}
        end
    end
  end

  # Back on the gap's node after a search that found nothing.
  defp resume(%{resume: {otherwise, []}} = s) do
    {node, _mv, neighbours, s} = Walk.look(%{s | resume: nil})
    give_up(otherwise, node, neighbours, s)
  end

  defp resume(%{resume: {otherwise, [host | hosts]}} = s),
    do: {:move, host, %{s | resume: {otherwise, hosts}}}

  # The hosts to move through from the end of `trail` (hosts from the gap's) back to the gap.
  defp way_back(_gap_host, []), do: []
  defp way_back(gap_host, trail), do: Enum.reverse([gap_host | Enum.drop(trail, -1)])

  # What an unbridged break leaves: a broken answer, an exit as the vectors say, or an
  # entry that is a gap (then, on the middle branch, back to the first node and forward).
  defp give_up(:broken, _node, _neighbours, s), do: done(:broken, s)
  defp give_up(:exited, _node, _neighbours, s), do: done(:exited, s)

  defp give_up(:gap, node, neighbours, s),
    do: entered(node, neighbours, Map.put(s, :entry, :gap))

  defp mv, do: A.store_get({:lats, :mv})
  defp entrance?, do: A.store_get({:lats, :entrance}, true)

  defp add_break(s, node, kind, at),
    do: %{s | breaks: s.breaks ++ [brk(node, kind, at, nil, nil)]}

  defp brk(node, kind, at, to, ring),
    do: %{node: node, kind: kind, at: at, bridged_to: to, ring: ring, through: nil}

  # A zone the tag passed through unseen, between stay `before` and stay `after`.
  defp unseen(node, before, after_),
    do: %{node: node, arrived_at: before.left_at, left_at: after_.arrived_at}

  defp local(nil, s, _fun), do: done(:broken, s)
  defp local(stay, s, fun), do: fun.(stay, s)

  defp entry(node, stay), do: %{node: node, arrived_at: stay.arrived_at, left_at: stay.left_at}

  defp status(%{to: nil}), do: :present
  defp status(%{to: :infinity}), do: :exited
  defp status(%{to: :pending}), do: :in_transit
  defp status(_), do: :broken

  defp done(status, s) do
    answer =
      {:ok, %{path: Query.merge(s.path), entry: Map.get(s, :entry, :broken), status: status}}

    Walk.finish(answer, s, true)
  end
end
