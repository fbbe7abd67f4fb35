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

  Arguments: `:tag` (required), `:label`, `:report` (contact the cloud,
  default true), `:cloud`, `:max_hops` (default 500).
  """
  use Tartarus.Agent, ships: [TartarusLats.Query, TartarusLats.Query.Walk]

  alias TartarusLats.Query
  alias TartarusLats.Query.Walk

  @impl true
  def init(args), do: step(args |> Walk.new(:where_is) |> Map.put(:at, nil))

  @impl true
  def handle_arrival(_ctx, s), do: step(s)

  @impl true
  def handle_move_failed(dest, _reason, _ctx, s), do: Walk.move_failed(s, dest, &step/1)

  @doc false
  def step(s) do
    {node, mv, neighbours, s} = Walk.look(s)

    case Query.follow(mv, s.tag, s.at) do
      {:found, here} ->
        Walk.finish({:in_zone, here}, s, true)

      {:next, next, t} ->
        Walk.go(neighbours, next, %{s | at: t}, fn ->
          Walk.finish({:in_transit, node}, s, true)
        end)

      :left_building ->
        Walk.finish(:left_building, s, true)

      :in_transit ->
        Walk.finish({:in_transit, node}, s, true)

      :no_trace when s.at != nil ->
        Walk.finish({:in_transit, node}, s, true)

      :no_trace ->
        Walk.search(s, :not_found)
    end
  end
end
