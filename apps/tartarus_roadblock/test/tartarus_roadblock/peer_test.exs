defmodule TartarusRoadblock.PeerTest do
  # The roadblock on real BEAM nodes: every host on a node of its own (`:peer`); the arena
  # stays on this node, and the robot hosts' plugins reach it across the network.
  use ExUnit.Case, async: false

  @moduletag :peer
  @moduletag timeout: 180_000

  @outcome [
    :rescued,
    :chosen_robot,
    :santa_arrived,
    :agent_hops,
    :seconds,
    :santa_arrival_s,
    :rescue_done_s,
    :claus_docked,
    :block_final,
    :candidates,
    :hosts_visited
  ]

  test "auto mode on peer nodes: the same rescue as on virtual hosts" do
    {:ok, %{summary: p}} = TartarusRoadblock.run(seed: 1, mode: :peer, out: false)
    assert p.mode == :peer
    assert p.rescued and p.chosen_robot == "claus" and p.santa_arrived and p.claus_docked
    {:ok, %{summary: v}} = TartarusRoadblock.run(seed: 1, out: false)
    assert Map.take(p, @outcome) == Map.take(v, @outcome)
  end
end
