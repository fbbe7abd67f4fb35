defmodule TartarusLats.ExperimentTest do
  use ExUnit.Case, async: false

  @tag timeout: 120_000
  @tag :tmp_dir
  test "a small run: every answer correct, few cloud connections, report written", %{tmp_dir: dir} do
    result =
      TartarusLats.Experiment.run(nodes: 10, minutes: 5, queries: 6, seed: 1, progress: false)

    s = result.summary

    for key <-
          ~w(queries correct cloud_connections_centralized cloud_connections_agents cloud_bytes_centralized cloud_bytes_agents median_query_hops)a,
        do: assert(Map.has_key?(s, key))

    assert s.queries == 6
    assert s.correct == 6
    assert s.correct_centralized == 6
    assert s.cloud_connections_agents <= 0.1 * s.cloud_connections_centralized

    Mix.Tasks.Tartarus.Lats.write_report(dir, result)

    for f <-
          ~w(queries.csv cloud_connections.csv cloud_connections.svg rssi.svg hops.svg summary.json summary.md),
        do: assert(File.exists?(Path.join(dir, f)), f)
  end
end
