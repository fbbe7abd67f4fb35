defmodule TartarusLats.Demo do
  @moduledoc false
  # LATS's part of `mix tartarus.demo`: a short run of both designs on the 50-node building.
  @behaviour TartarusTools.Demo
  import TartarusTools.Demo, only: [say: 1]

  @impl true
  def title, do: "LATS: location queries as agents vs a cloud, 50-node building"

  @impl true
  def run(opts) do
    out = Path.expand(Path.join(opts[:out], "lats"))

    {:ok, %{summary: s}} =
      TartarusLats.Experiment.run(
        minutes: 6,
        queries: 9,
        seed: opts[:seed] || 1,
        out: out,
        quiet: true
      )

    say(
      "#{s.queries} queries (Trace, Where is X, Where am I) on #{s.nodes} nodes with #{s.bearers} tag bearers: #{s.correct} correct (cloud: #{s.correct_centralized})"
    )

    say(
      "cloud connections: centralized #{s.cloud_connections_centralized}, agents #{s.cloud_connections_agents}; median query hops #{s.median_query_hops}"
    )

    say("report: #{out}/summary.md, plots: #{out}/cloud_connections.svg, #{out}/rssi.svg")
    :ok
  end
end
