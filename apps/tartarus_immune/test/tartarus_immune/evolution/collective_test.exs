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
end
