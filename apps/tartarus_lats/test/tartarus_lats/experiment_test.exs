defmodule TartarusLats.ExperimentTest do
  use ExUnit.Case, async: false
  doctest TartarusLats.Experiment
  doctest TartarusLats.Experiment.Queries

  @tag timeout: 120_000
  @tag :tmp_dir
  test "a small run: every answer correct, few cloud connections, report written", %{tmp_dir: dir} do
    assert {:ok, result} =
             TartarusLats.Experiment.run(
               nodes: 10,
               minutes: 5,
               queries: 6,
               seed: 1,
               quiet: true,
               out: dir
             )

    s = result.summary

    for key <-
          ~w(queries correct cloud_connections_centralized cloud_connections_agents cloud_bytes_centralized cloud_bytes_agents median_query_hops seed scenario steps)a,
        do: assert(Map.has_key?(s, key))

    assert s.steps == 300
    assert s.queries == 6
    assert s.correct == 6
    assert s.correct_centralized == 6
    assert s.cloud_connections_agents <= 0.1 * s.cloud_connections_centralized

    for f <-
          ~w(queries.csv cloud_connections.csv cloud_connections.svg cloud_connections_agents.svg rssi.svg hops.svg latency.svg series.csv summary.json summary.md),
        do: assert(File.exists?(Path.join(dir, f)), f)

    assert File.read!(Path.join(dir, "summary.md")) =~ "cloud connections, agents / centralized"
  end

  # The thesis's scenario 2: an agent contacts the cloud from every node where it finds data
  # of its tag. Both rules are reported for the same queries; the plots and
  # cloud_connections_agents count the rule applied.
  @tag timeout: 120_000
  test "cloud contacts per node (default) and per query, both reported" do
    small = [nodes: 10, minutes: 3, queries: 3, seed: 3, quiet: true, out: false]
    {:ok, %{summary: n}} = TartarusLats.Experiment.run(small)
    {:ok, %{summary: q}} = TartarusLats.Experiment.run(small ++ [agent_cloud: :per_query])

    assert n.agent_cloud == "per_node" and q.agent_cloud == "per_query"
    assert n.cloud_connections_agents == n.cloud_connections_agents_per_node
    assert q.cloud_connections_agents == q.cloud_connections_agents_per_query
    assert q.cloud_connections_agents <= q.queries
    # Same walks, so the same costs either way; a query's data spans several nodes.
    assert n.cloud_connections_agents_per_node == q.cloud_connections_agents_per_node
    assert n.cloud_connections_agents_per_node > n.cloud_connections_agents_per_query
  end

  # Nodes die and come back during the run: the run goes on, queries are asked from nodes
  # that are up, and an answer that needed a dead node names it (partial, not complete).
  @tag timeout: 120_000
  test "nodes killed mid-run: the run goes on and answers name the nodes they missed" do
    base = [nodes: 20, minutes: 8, queries: 30, seed: 2, down_s: 90, quiet: true, out: false]
    {:ok, %{summary: s}} = TartarusLats.Experiment.run(base ++ [kill_nodes: 4])

    assert s.queries == 30
    assert s.node_kills >= 3
    assert s.nodes_down_at_end == 0
    assert s.answers_partial > 0
    assert s.answers_incomplete >= s.answers_partial

    # Without kills the same seed has nothing partial.
    {:ok, %{summary: clean}} = TartarusLats.Experiment.run(base)
    assert clean.answers_partial == 0 and clean.node_kills == 0
  end

  test "options are checked in one place, naming key, expectation and value" do
    assert {:error, msg} = TartarusLats.Experiment.run(nodes: 5)
    assert msg =~ "for key :nodes: expected an integer >= 10, got: 5"
    assert {:error, msg} = TartarusLats.Experiment.run(mode: :cloud)
    assert msg =~ "for key :mode: expected"
    assert {:error, msg} = TartarusLats.Experiment.run(minutes: 0)
    assert msg =~ "for key :minutes: expected a positive integer, got: 0"
    assert {:error, msg} = TartarusLats.Experiment.run(noise_db: -1)
    assert msg =~ "for key :noise_db: expected a number from 0 to 40, got: -1"
    assert {:error, msg} = TartarusLats.Experiment.run(release: :sometimes)
    assert msg =~ "for key :release: expected"
  end
end
