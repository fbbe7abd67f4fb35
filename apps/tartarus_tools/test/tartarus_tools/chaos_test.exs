defmodule TartarusTools.ChaosTest do
  # The chaos harness at a tiny size on real peer nodes: its keys and the invariants the
  # platform promises with persistence (no duplicate, no loss, no transient duplicate).
  use ExUnit.Case, async: false

  @moduletag :peer

  @moduletag timeout: 180_000

  setup_all do
    :ok = TartarusTools.Peer.ensure_distributed("chaos_test")
    :ok
  end

  # Two nodes, one kill, one partition, persistence.
  @small [nodes: 2, agents: 8, migrations: 60, kills: 1, partitions: 1, persist: true]

  test "a small run with kills, partitions, clones, posts, replays from a rogue node and a census" do
    r = TartarusTools.Chaos.run(@small ++ [seed: 3, census_ms: 200, replays: 20])

    assert r.duplicates == 0
    assert r.lost == 0
    assert r.transient_duplicates == 0
    assert r.agents_end == r.agents_start + r.clones + r.untracked_agents
    assert r.census_rounds > 0
    # Captured sealed prepares sent again from a rogue node: none admitted (no duplicate above).
    assert r.replays == 20
    assert r.posts == r.acknowledged + Enum.sum(Map.values(r.post_failures))
    # Messages missing from an agent restored from its arrival snapshot are excused (no
    # durability mode); no other.
    assert r.acknowledged_missing == r.acknowledged_missing_after_kill
    assert r.acknowledged_of_lost_agents == 0

    for key <- [:migrations_done, :agent_moves, :census_unanswered, :still_in_doubt, :wall_ms] do
      assert is_integer(r[key]), "#{key}"
    end
  end

  test "a small durable run: no acknowledged message is missing, kills included" do
    r =
      TartarusTools.Chaos.run(
        @small ++ [seed: 2, census_ms: 0, replays: 0, host_opts: [durable: true]]
      )

    assert r.duplicates == 0
    assert r.lost == 0
    assert r.acknowledged > 0
    assert r.acknowledged_missing == 0
    assert r.acknowledged_of_lost_agents == 0
  end

  test "a small run with host servers killed: their agents live on, none lost or duplicated" do
    r =
      TartarusTools.Chaos.run(
        Keyword.merge(@small, kills: 0, server_kills: 3, seed: 4, census_ms: 200, replays: 0)
      )

    assert r.server_kills == 3 and r.kills == 0
    assert r.duplicates == 0
    assert r.lost == 0
    assert r.transient_duplicates == 0
    # No node was killed: every acknowledged message is in its agent.
    assert r.acknowledged_missing == 0
  end

  test "--durable is refused with a clear error on a platform without it" do
    probe = :"chaos_test_probe_#{System.unique_integer([:positive])}"

    case Tartarus.start_host(probe, durable: true) do
      # The platform has the option: nothing to refuse.
      {:ok, host} ->
        Tartarus.stop_host(host)

      {:error, _} ->
        assert_raise Mix.Error, ~r/--durable needs a platform/, fn ->
          Mix.Tasks.Tartarus.Chaos.run(["--durable", "--nodes", "2"])
        end
    end
  end
end
