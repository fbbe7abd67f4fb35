defmodule TartarusLats.Query.WhereAmI do
  @moduledoc """
  Where am I? (thesis §3.3.5, query 1, Figure 3.5) as an ordinary mobile
  agent.

  The user releases it, with the tag they wear, on a node one hop from
  where they stand; it follows the user's MVF to the node whose zone holds
  them now and answers `{:in_zone, node}` (or `:left_building`,
  `:not_found`, `{:in_transit, node}`), exactly as
  `TartarusLats.Query.WhereIs` does for someone else. (Figure 3.5 jumps to
  a random node when it finds no trace; this agent searches
  conscientiously, which also knows when the network is exhausted.)

  Arguments: `:tag` (the user's own, required), `:label`, `:report`,
  `:max_hops`.
  """
  use Tartarus.Agent,
    ships: [TartarusLats.Query, TartarusLats.Query.Walk, TartarusLats.Query.WhereIs]

  alias TartarusLats.Query.{Walk, WhereIs}

  @impl true
  def init(args) do
    args
    |> Walk.new(:where_am_i)
    |> Map.merge(%{at: nil, repair: false, bridge: nil, bridges: []})
    |> WhereIs.step()
  end

  @impl true
  def handle_arrival(_ctx, s), do: WhereIs.step(s)

  @impl true
  def handle_move_failed(dest, _reason, _ctx, s),
    do: Walk.move_failed(s, dest, &WhereIs.step/1)
end
