defmodule TartarusImmune.Evolution.CollectiveTest do
  use ExUnit.Case, async: false

  alias TartarusImmune.Evolution.Collective

  # 3 robots x 30 iterations, publishing every 5: 18 publications.
  @opts [iterations: 30, test_episodes: 1, seed: 5]

  test "broadcast: every publication goes to both other robots, counted by the platform" do
    {:ok, r} = Collective.run([scheme: :broadcast] ++ @opts)
    assert r.communications.broadcast_messages == 18 * 2
    assert r.communications.broadcasts_received == 18 * 2
    assert r.communications.departures == 0
    assert length(r.per_robot) == 3
  end

  test "a packet agent: one hop per publication; reproducible" do
    {:ok, a} = Collective.run([scheme: :ipkt] ++ @opts)
    assert a.communications.departures == 18 and a.communications.arrivals == 18
    assert a.communications.broadcast_messages == 0
    {:ok, b} = Collective.run([scheme: :ipkt] ++ @opts)
    assert a.per_robot == b.per_robot
  end

  test "without sharing no shared antibody is ever chosen" do
    {:ok, r} = Collective.run([scheme: :none] ++ @opts)
    assert Enum.all?(r.per_robot, &(&1.external_selections == 0))
    assert Enum.sum(Map.values(r.communications)) == 0
  end

  test "a dynamic network: links come and go, broadcasts reach only the robots linked then" do
    {:ok, r} = Collective.run([scheme: :broadcast, dynamic: 0.5, flap_every: 5] ++ @opts)
    assert r.link_ticks > 0 and r.link_flaps > 0 and r.links_up < 1.0
    pubs = r.per_robot |> Enum.map(& &1.publications) |> Enum.sum()
    reached = r.per_robot |> Enum.map(& &1.reached) |> Enum.sum()
    assert pubs == 18
    # fewer than both other robots each time, and the platform counted what was reached
    assert reached < 18 * 2
    assert r.communications.broadcast_messages == reached
    assert r.communications.broadcasts_received == reached
    # the static mesh as before: no tick
    {:ok, s} = Collective.run([scheme: :broadcast] ++ @opts)
    assert s.link_ticks == 0 and s.links_up == 1.0
  end

  test "a dynamic network: the packet agent stays where it is when its host has no link" do
    {:ok, a} = Collective.run([scheme: :ipkt, dynamic: 0.5, flap_every: 5] ++ @opts)
    stays = a.per_robot |> Enum.map(& &1.stays) |> Enum.sum()
    assert stays > 0 and a.communications.departures == 18 - stays
    {:ok, b} = Collective.run([scheme: :ipkt, dynamic: 0.5, flap_every: 5] ++ @opts)
    assert a.per_robot == b.per_robot and a.link_flaps == b.link_flaps
  end
end
