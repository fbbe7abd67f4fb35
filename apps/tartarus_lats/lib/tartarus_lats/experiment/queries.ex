defmodule TartarusLats.Experiment.Queries do
  @moduledoc """
  The queries of the LATS comparison (`TartarusLats.Experiment`): when they are released,
  about whom and from where (drawn from the seed), their ground truth, and asking them of
  both designs (the agents, released together, and the cloud). See
  `TartarusLats.Experiment`, "Queries and ground truth".
  """

  alias Tartarus.Clock
  alias TartarusLats.{Building, Cloud, Deployment, Judge, World}

  require Tartarus.Clock

  @settle_inside 20
  @settle_outside 30
  @warmup 120

  @doc "The warm-up (world seconds) before the first query and the first node kill."
  @spec warmup() :: pos_integer()
  def warmup, do: @warmup

  @doc """
  When the `n` queries are released in a run of `duration` world seconds:
  `%{second => [type]}`, batches of three (one of each type) at `ceil(n / 3)` instants
  after the #{@warmup} s warm-up. Settled release: evenly spread (each batch then waits
  for a settled target). Random release: each batch at a world second drawn uniformly
  after the warm-up, from the seed.

      iex> TartarusLats.Experiment.Queries.schedule(4, 300, :settled, 1)
      %{120 => [:trace, :where_is, :where_am_i], 210 => [:trace]}
  """
  @spec schedule(pos_integer(), pos_integer(), :random | :settled, integer()) ::
          %{non_neg_integer() => [atom()]}
  def schedule(n, duration, release, seed) do
    instants = max(1, div(n + 2, 3))
    span = max(duration - @warmup, 1)
    rng = :rand.seed_s(:exsss, {seed, 3301, 17})

    {acc, _rng} =
      Enum.reduce(0..(instants - 1), {%{}, rng}, fn k, {acc, rng} ->
        {t, rng} =
          case release do
            :settled ->
              {min(duration, @warmup + div(k * span, instants)), rng}

            :random ->
              {x, rng} = :rand.uniform_s(span, rng)
              {min(duration, @warmup + x), rng}
          end

        types = Enum.take([:trace, :where_is, :where_am_i], min(3, n - 3 * k))
        {Map.update(acc, t, types, &(&1 ++ types)), rng}
      end)

    acc
  end

  @doc """
  Whether a bearer is **settled** now: in its current zone for at least #{@settle_inside}
  s, or out of the building for at least #{@settle_outside} s.
  """
  @spec settled?(World.t(), term()) :: boolean()
  def settled?(world, name) do
    case World.visited_path(world, name) do
      [] ->
        false

      path ->
        last = List.last(path)
        t = world.time

        if last.left_at == nil,
          do: t - last.entered_at >= @settle_inside,
          else: t - last.left_at >= @settle_outside
    end
  end

  defp inside?(world, name), do: World.current_zone(world, name) != :outside

  # A bearer a query may be about: settled (settled release), or one who has come into the
  # building at some time (random release: moving or not).
  defp eligible?(world, name, :settled), do: settled?(world, name)
  defp eligible?(world, name, :random), do: World.visited_path(world, name) != []

  @doc """
  The `k`-th query (counting from 0) of `type` in the deployment `dep` now, drawn with
  `rng`: `{query, rng}`, or `{nil, rng}` when no bearer is eligible yet (settled release:
  none settled; random release: none has come into the building) or no start node is up.
  Trace targets rotate over the scripted bearers; Where am I starts on a neighbour of the
  bearer's zone that is up; the others on a random node that is up.
  """
  @spec pick(atom(), World.t(), Deployment.t(), :rand.state(), non_neg_integer(), atom()) ::
          {map() | nil, :rand.state()}
  def pick(type, world, dep, rng, k, release) do
    names = World.names(world)
    scripted = Enum.filter(names, &(Map.fetch!(world.bearers, &1).kind == :scripted))
    # Queries are asked from nodes that are up.
    nodes = Deployment.live_nodes(dep)

    candidates =
      case type do
        :trace ->
          # Rotate over the scripted bearers (Fig. 3.9), starting with the k-th.
          rot = rotate(scripted, div(k, 3))
          rot |> Enum.filter(&eligible?(world, &1, release)) |> Enum.take(1)

        :where_is ->
          Enum.filter(names, &eligible?(world, &1, release))

        :where_am_i ->
          Enum.filter(names, &(eligible?(world, &1, release) and inside?(world, &1)))
      end

    case candidates do
      [] ->
        {nil, rng}

      _ ->
        {i, rng} = :rand.uniform_s(length(candidates), rng)
        name = Enum.at(candidates, i - 1)

        {start, rng} =
          case type do
            :where_am_i ->
              ns = Building.neighbours(world.building, World.current_zone(world, name))
              ns = Enum.filter(ns, &(&1 in nodes))
              if ns == [], do: {nil, rng}, else: pick_one(ns, rng)

            _ ->
              pick_one(nodes, rng)
          end

        if start, do: {query(k, type, name, start, world, dep), rng}, else: {nil, rng}
    end
  end

  defp pick_one(list, rng) do
    {j, rng} = :rand.uniform_s(length(list), rng)
    {Enum.at(list, j - 1), rng}
  end

  defp query(k, type, name, start, world, dep) do
    %{
      id: k + 1,
      type: type,
      person: name,
      tag: World.tag(world, name),
      start: start,
      host: dep.hosts[start],
      time: world.time,
      settled: settled?(world, name),
      path: World.visited_path(world, name),
      truth: truth(type, world, name)
    }
  end

  defp rotate([], _n), do: []

  defp rotate(list, n) do
    n = rem(n, length(list))
    Enum.drop(list, n) ++ Enum.take(list, n)
  end

  defp truth(:trace, world, name) do
    path = World.visited_path(world, name)

    %{
      zones: Enum.map(path, & &1.zone),
      path: path,
      status: if(inside?(world, name), do: :present, else: :exited)
    }
  end

  defp truth(_type, world, name) do
    case World.current_zone(world, name) do
      :outside -> :left_building
      zone -> {:in_zone, zone}
    end
  end

  @doc """
  Asks a batch of queries: releases their agents together (`TartarusLats.release/4`,
  contacting the cloud by `rule`), waits for every result, then asks the cloud the same
  questions; each query comes back with both answers, judged (`TartarusLats.Judge`), the
  agent's hops, route, cloud contacts and latency (ms, on this VM's `Tartarus.Clock`). `repair`: the
  Where is X agents bridge broken chains (`TartarusLats.Query.WhereIs`).
  """
  @spec ask([map()], Deployment.t(), :per_node | :per_query, boolean()) :: [map()]
  def ask(batch, dep, rule, repair \\ false)
  def ask([], _dep, _rule, _repair), do: []

  def ask(batch, dep, rule, repair) do
    released =
      Enum.map(batch, fn q ->
        t0 = Clock.monotonic_time(:microsecond)

        {:ok, id} =
          TartarusLats.release(q.host, q.type, q.tag,
            label: "#{q.type}(#{q.person})#{q.id}",
            seed: {:lats_query, q.id, q.time},
            cloud: rule,
            repair: repair
          )

        {q, id, t0}
      end)

    # Latency on this VM's Tartarus.Clock (design time): from the release to the result's
    # arrival here (the agent starts and ends on different nodes, whose clocks are not this
    # one's in peer mode).
    arrived = collect(Map.new(released, fn {_q, id, _t0} -> {id, nil} end), 120_000)

    Enum.map(released, fn {q, id, t0} ->
      {r, at} = Map.fetch!(arrived, id)
      central = Cloud.query(dep.cloud, q.type, q.start, q.tag)

      Map.merge(q, %{
        answer: r.answer,
        hops: r.hops,
        ms: (at - t0) / 1000,
        route: r.route,
        answered_at: r.answered_at,
        per_node_contacts: r.per_node_contacts,
        freshness: r.freshness,
        evidence_age_s: r.evidence_at && r.asked_at - r.evidence_at,
        complete: r.complete,
        unreachable: r.unreachable,
        breaks: Map.get(r, :breaks, []),
        per_query_contacts: r.per_query_contacts,
        central: central,
        correct: Judge.correct?(q.type, r.answer, q.path, q.time),
        correct_centralized: Judge.correct?(q.type, central, q.path, q.time),
        time_error: Judge.time_error(q.type, r.answer, q.truth)
      })
    end)
  end

  # Results of the released agents in the order they arrive, each with its arrival time.
  defp collect(pending, timeout) do
    if Enum.all?(pending, fn {_id, v} -> v != nil end) do
      pending
    else
      Clock.receive do
        {:tartarus_result, id, result} when is_map_key(pending, id) ->
          collect(Map.put(pending, id, {result, Clock.monotonic_time(:microsecond)}), timeout)

        {:tartarus_removed, id, reason} when is_map_key(pending, id) ->
          raise "LATS query agent #{id} was removed: #{inspect(reason)}"
      after
        timeout -> raise "LATS query agents did not answer within #{timeout} ms"
      end
    end
  end
end
