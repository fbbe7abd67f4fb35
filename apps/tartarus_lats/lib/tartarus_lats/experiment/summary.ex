defmodule TartarusLats.Experiment.Summary do
  @moduledoc """
  The summary of a LATS run (`TartarusLats.Experiment`): both designs' answers, judged
  by `TartarusLats.Judge`, and what each cost in cloud connections and bytes.
  """

  alias TartarusLats.Deployment
  alias TartarusTools.Stats

  @doc """
  The run's summary: the run's `meta` keys, and from the judged queries (`results`, in
  order), the cloud's counters (`stats`: `TartarusLats.Cloud.stats/1`) and the deployment
  `dep`: answers correct per design (and by settled or moving target), cloud connections
  and bytes per design, hops, latency, trace time error, per query type, and the input's
  counters (the keys are listed by `mix help tartarus.lats`).
  """
  @spec summarize([map()], map(), Deployment.t(), map()) :: map()
  def summarize(results, stats, dep, meta) do
    hops = results |> Enum.map(& &1.hops) |> Enum.sort()
    ms = results |> Enum.map(& &1.ms) |> Enum.sort()
    c = stats.connections.centralized
    a = stats.connections.agents

    by_type =
      results
      |> Enum.group_by(& &1.type)
      |> Map.new(fn {type, rs} ->
        {to_string(type),
         %{
           queries: length(rs),
           correct: Enum.count(rs, & &1.correct),
           complete_wrong: Enum.count(rs, &(&1.complete and not &1.correct)),
           median_hops: Stats.median(Enum.map(rs, & &1.hops))
         }}
      end)

    {settled, moving} = Enum.split_with(results, & &1.settled)

    Map.merge(meta, %{
      queries: length(results),
      correct: Enum.count(results, & &1.correct),
      # Correctness (see correct?/4) by whether the target was settled at release.
      queries_settled: length(settled),
      queries_moving: length(moving),
      correct_settled: share(settled, & &1.correct),
      correct_moving: share(moving, & &1.correct),
      correct_settled_centralized: share(settled, & &1.correct_centralized),
      correct_moving_centralized: share(moving, & &1.correct_centralized),
      correct_centralized: Enum.count(results, & &1.correct_centralized),
      cloud_connections_centralized: c,
      cloud_connections_agents: a,
      cloud_connection_ratio: if(c > 0, do: Float.round(a / c, 4), else: nil),
      # What the agents' design costs under each rule (the run applied `agent_cloud`).
      cloud_connections_agents_per_node: Enum.sum(Enum.map(results, & &1.per_node_contacts)),
      cloud_connections_agents_per_query: Enum.sum(Enum.map(results, & &1.per_query_contacts)),
      answers_stale: Enum.count(results, &(&1.freshness == :stale)),
      answers_incomplete: Enum.count(results, &(not &1.complete)),
      # Answers that said they were complete and were wrong: what a user would trust.
      answers_complete_wrong: Enum.count(results, &(&1.complete and not &1.correct)),
      # Breaks of the chain of motion vectors the agents met; bridged with no zone unknown;
      # bridged over two rings with the zone between unknown (`TartarusLats.Query.Trace`).
      breaks: count_breaks(results, fn _ -> true end),
      breaks_bridged: count_breaks(results, &TartarusLats.Query.Walk.bridged?/1),
      breaks_bridged_far:
        count_breaks(
          results,
          &(&1.bridged_to != nil and not TartarusLats.Query.Walk.bridged?(&1))
        ),
      # Answers that name nodes they could not reach (a killed node, a cut link).
      answers_partial: Enum.count(results, &(&1.unreachable != [])),
      cloud_bytes_centralized: stats.bytes.centralized,
      cloud_bytes_agents: stats.bytes.agents,
      median_query_hops: Stats.median(hops),
      max_query_hops: List.last(hops),
      median_query_ms: Stats.median(ms) && Float.round(Stats.median(ms) * 1.0, 3),
      trace_time_error_s:
        Stats.median(Enum.reject(Enum.map(results, & &1.time_error), &is_nil/1)),
      by_type: by_type,
      world_seconds: dep.time,
      input: if(dep.replay, do: "replay", else: "simulated"),
      replay_records: dep.input.records,
      replay_bad_records: dep.input.bad_records,
      replay_garbage_bytes: dep.input.garbage_bytes
    })
  end

  defp count_breaks(results, fun),
    do: results |> Enum.flat_map(&Map.get(&1, :breaks, [])) |> Enum.count(fun)

  # The share of `list` for which `fun` holds (4 decimals), nil for an empty list.
  defp share([], _fun), do: nil
  defp share(list, fun), do: Float.round(Enum.count(list, fun) / length(list), 4)
end
