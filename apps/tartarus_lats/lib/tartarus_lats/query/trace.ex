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

  Arguments: `:tag` (required), `:label`, `:report`, `:cloud`, `:max_hops`.
  """
  use Tartarus.Agent, ships: [TartarusLats.Query, TartarusLats.Query.Walk]

  alias TartarusLats.{MotionVectors, Query}
  alias TartarusLats.Query.Walk

  @impl true
  def init(args) do
    s =
      args
      |> Walk.new(:trace)
      |> Map.merge(%{phase: :search, branch: nil, at: nil, path: [], found: nil, back_to: []})

    step(s)
  end

  @impl true
  def handle_arrival(_ctx, s), do: step(s)

  @impl true
  def handle_move_failed(dest, _reason, _ctx, s), do: Walk.move_failed(s, dest, &step/1)

  defp step(s) do
    {node, mv, neighbours, s} = Walk.look(s)
    act(s.phase, node, mv, neighbours, s)
  end

  defp act(:search, node, mv, neighbours, s) do
    case Query.latest(mv, s.tag) do
      nil ->
        Walk.search(s, :not_found)

      stay ->
        branch = if stay.to in [nil, :infinity], do: :last, else: :middle
        s = %{s | branch: branch, phase: :back, found: {node, stay}}
        back(node, stay, neighbours, s)
    end
  end

  defp act(:back, node, mv, neighbours, s) do
    case mv && MotionVectors.departure(mv, s.tag, s.at) do
      %{} = stay -> back(node, stay, neighbours, s)
      _ -> done(:broken, s)
    end
  end

  defp act(:return, node, _mv, neighbours, s), do: return(node, neighbours, s)

  defp act(:forward, node, mv, neighbours, s) do
    case mv && MotionVectors.arrival(mv, s.tag, s.at) do
      %{} = stay -> forward(node, stay, neighbours, %{s | path: s.path ++ [entry(node, stay)]})
      _ -> done(:broken, s)
    end
  end

  # Walking back along MVB, pushing every stay on the stack (the path so far).
  defp back(node, stay, neighbours, s) do
    s = %{s | path: [entry(node, stay) | s.path]}

    case stay.from do
      from when from in [:infinity, :pending] ->
        s = Map.put(s, :entry, entry_kind(from))
        {_, found} = s.found

        if s.branch == :last do
          done(status(found), s)
        else
          # Back to the first node with a trace, along the stack, then forward from there.
          nodes = s.path |> Enum.map(& &1.node) |> Enum.dedup() |> tl()
          return(node, neighbours, %{s | phase: :return, back_to: nodes})
        end

      ^node ->
        # A loop here -> here: the previous stay is on this node too.
        local(
          MotionVectors.departure(mv(), s.tag, stay.from_left_at),
          s,
          &back(node, &1, neighbours, &2)
        )

      prev ->
        Walk.go(neighbours, prev, %{s | at: stay.from_left_at}, fn -> done(:broken, s) end)
    end
  end

  defp return(node, neighbours, %{back_to: []} = s) do
    {_, found} = s.found
    forward(node, found, neighbours, %{s | phase: :forward})
  end

  defp return(_node, neighbours, %{back_to: [next | rest]} = s),
    do: Walk.go(neighbours, next, %{s | back_to: rest}, fn -> done(:broken, s) end)

  # Walking forward along MVF from `stay` (already on the path), queueing every stay.
  defp forward(node, stay, neighbours, s) do
    case stay.to do
      next when next in [nil, :infinity, :pending] ->
        done(status(stay), s)

      ^node ->
        local(MotionVectors.arrival(mv(), s.tag, stay.to_arrived_at), s, fn next, s ->
          forward(node, next, neighbours, %{s | path: s.path ++ [entry(node, next)]})
        end)

      next ->
        Walk.go(neighbours, next, %{s | at: stay.to_arrived_at}, fn -> done(:broken, s) end)
    end
  end

  defp mv, do: Tartarus.Agent.store_get({:lats, :mv})

  # A stay that came "from outside" on a node with no door to the outside is a hand-over
  # that was lost (a wrong or missed hand-over, a bearer walking through a dead node's
  # zone): the chain is broken there, and the answer says so (`:gap`, never complete).
  defp entry_kind(:infinity),
    do: if(Tartarus.Agent.store_get({:lats, :entrance}, true), do: :infinity, else: :gap)

  defp entry_kind(from), do: from

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
