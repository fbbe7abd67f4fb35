defmodule TartarusLats.ExperimentTest do
  use ExUnit.Case, async: false
  doctest TartarusLats.Experiment

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
          ~w(queries.csv cloud_connections.csv cloud_connections.svg rssi.svg hops.svg latency.svg series.csv summary.json summary.md),
        do: assert(File.exists?(Path.join(dir, f)), f)

    assert File.read!(Path.join(dir, "summary.md")) =~ "cloud connections, agents / centralized"
  end

  test "options are checked in one place, naming key, expectation and value" do
    assert {:error, msg} = TartarusLats.Experiment.run(nodes: 5)
    assert msg =~ "for key :nodes: expected an integer >= 10, got: 5"
    assert {:error, msg} = TartarusLats.Experiment.run(mode: :cloud)
    assert msg =~ "for key :mode: expected"
    assert {:error, msg} = TartarusLats.Experiment.run(minutes: 0)
    assert msg =~ "for key :minutes: expected a positive integer, got: 0"
  end
end
