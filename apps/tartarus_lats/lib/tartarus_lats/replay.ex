defmodule TartarusLats.Replay do
  @moduledoc """
  LATS on real recordings: a log of many receivers' RSSI readings
  (`TartarusLats.Replay.Log`) replayed into a LATS deployment, one node per receiver, and
  judged against the log's true positions beside two centralized baselines
  (`TartarusLats.Replay.Judge`). The rules are in docs/lats.md, "LATS on real BLE
  recordings"; `mix tartarus.lats --replay-log PATH --devices FILE` runs it.

      devices = TartarusLats.Replay.Devices.read!("../shared/data/ble-tetam/tetam.dev")
      c = TartarusLats.Replay.prepare("../shared/data/ble-tetam/tracks/straight_01.mbd", devices)
      r = TartarusLats.Replay.run(c, seed: 1)
      r.summary.lats.exact

  ## How a recording is replayed

  `prepare/3` reads the log, keeps the readings of one beacon (the one with most readings,
  or `:beacon`) from the receivers of the devices file (others are counted, never fed),
  and groups them into whole seconds from the first reading: a receiver's readings of one
  second become one sample, their mean rounded to a dBm (`TartarusLats.Replay.Log.per_second/1`).
  The beacon's id becomes a LATS tag `{uuid, 0, 0}` (`tag/1`).

  `run/2` starts a `TartarusLats.Deployment` on the devices' building
  (`TartarusLats.Replay.Devices.building/1`, the Delaunay neighbours), each node a real
  Tartarus host (virtual or `:peer`) with its receiver, database agent, tracker, zone
  decision and motion vectors, the node's calibration correction given to its tracker
  (`TartarusLats.Replay.Calibration`). The driver feeds every node the readings it logged,
  second by second, as fast as the nodes take them (deterministic: the deployment's
  barriers, `TartarusLats.Deployment`). After every second it reads which node holds the
  tag (`{:lats, :held}` in each node's store): LATS's decision of that second. At instants
  drawn from the seed it releases a Where is X and a Trace query agent from nodes drawn from
  the seed and judges their answers; the baselines answer at the same instants from their
  own decisions.
  """

  alias TartarusLats.{Building, Deployment, World}
  alias TartarusLats.Replay.{Calibration, Judge, Log}

  @doc """
  The LATS tag of a beacon id: 32 hex digits as they are, a shorter hex id (a MAC)
  left-padded with zeros; `{uuid, 0, 0}`.

      iex> TartarusLats.Replay.tag("e78f135624ce")
      {"00000000000000000000e78f135624ce", 0, 0}
  """
  @spec tag(String.t()) :: {String.t(), 0, 0}
  def tag(beacon), do: {String.pad_leading(String.downcase(beacon), 32, "0"), 0, 0}

  @doc """
  Reads a log (a path, or a parsed `TartarusLats.Replay.Log`) for the receivers of
  `devices` and returns the case a run replays: `%{name, building, beacon, tag, feed,
  raw, last, truth, t0, lines, readings, bad, unterminated, unknown_receivers}` where
  `feed` is `%{second => %{node => %{tag => rssi}}}` (raw, what the receivers logged), `raw`
  the beacon's `%{second => %{node => rssi}}`, `unknown_receivers` `%{receiver => readings}`
  of the receivers the devices file does not name (never fed). `check/2` says whether it
  can be judged. Options: `:beacon` (default: the beacon with most readings), `:name`.
  """
  @spec prepare(Path.t() | Log.t(), TartarusLats.Replay.Devices.t(), keyword()) :: map()
  def prepare(log, devices, opts \\ []) do
    {name, log} =
      if is_binary(log),
        do: {Keyword.get(opts, :name, log |> Path.basename() |> Path.rootname()), Log.read!(log)},
        else: {Keyword.get(opts, :name, "log"), log}

    beacon =
      Keyword.get_lazy(opts, :beacon, fn ->
        log.readings
        |> Enum.frequencies_by(& &1.beacon)
        |> Enum.max_by(&elem(&1, 1), fn -> {"", 0} end)
        |> elem(0)
      end)

    known = Map.new(devices, fn {id, d} -> {id, d.name} end)
    {t0, seconds} = Log.per_second(log)
    # A stretch of more than @max_gap s with no reading is shortened to @max_gap s (nothing
    # happens in it: walking it second by second only costs time and memory).
    {remap, gaps} = gaps(Map.keys(seconds))
    seconds = Map.new(seconds, fn {s, v} -> {Map.fetch!(remap, s), v} end)
    tag = tag(beacon)

    unknown =
      log.readings
      |> Enum.reject(&Map.has_key?(known, &1.receiver))
      |> Enum.frequencies_by(& &1.receiver)

    feed =
      Map.new(seconds, fn {s, by_rx} ->
        nodes =
          for {rx, by_beacon} <- by_rx,
              node = known[rx],
              node != nil,
              into: %{},
              do: {node, Map.new(by_beacon, fn {b, rssi} -> {tag(b), rssi} end)}

        {s, nodes}
      end)

    raw =
      Map.new(feed, fn {s, by_node} ->
        {s,
         Map.new(Enum.filter(by_node, fn {_n, m} -> is_map_key(m, tag) end), fn {n, m} ->
           {n, m[tag]}
         end)}
      end)

    building = TartarusLats.Replay.Devices.building(devices)
    last = if seconds == %{}, do: 0, else: seconds |> Map.keys() |> Enum.max()

    positions =
      log |> Log.positions(t0, beacon) |> Map.new(fn {s, p} -> {Map.fetch!(remap, s), p} end)

    %{
      name: name,
      building: building,
      positions: positions,
      beacon: beacon,
      tag: tag,
      feed: feed,
      raw: raw,
      last: last,
      t0: t0,
      truth: Judge.truth(building, positions, last),
      lines: log.lines,
      readings: length(log.readings),
      bad: log.bad,
      unterminated: log.unterminated,
      unknown_receivers: unknown,
      gaps: gaps
    }
  end

  @doc """
  Whether a case (`prepare/3`) can be judged with `warmup` seconds left unjudged at its
  start: `:ok`, or `{:error, why}` in one line naming the track, when the log has no valid
  reading, no reading from a receiver of the devices file, no true position of the beacon,
  or no second after the warm-up. A run of such a case would judge nothing, and nothing is
  not a pass.

      iex> c = %{name: "t", readings: 0, lines: 2, bad: [{1, "x"}, {2, "y"}], feed: %{}}
      iex> TartarusLats.Replay.check(c, 5)
      {:error, "t: no valid reading (2 lines, 2 bad)"}
  """
  @spec check(map(), non_neg_integer()) :: :ok | {:error, String.t()}
  def check(c, warmup) do
    cond do
      c.readings == 0 ->
        {:error, "#{c.name}: no valid reading (#{c.lines} lines, #{length(c.bad)} bad)"}

      Enum.all?(c.feed, fn {_s, by_node} -> by_node == %{} end) ->
        {:error,
         "#{c.name}: no reading from a receiver of the devices file (unknown receivers: " <>
           "#{c.unknown_receivers |> Map.keys() |> Enum.sort() |> Enum.join(", ")})"}

      c.positions == %{} ->
        {:error,
         "#{c.name}: no true position of beacon #{c.beacon} (no x, y columns): nothing to judge against"}

      not Enum.any?(Map.keys(c.truth), &(&1 > warmup)) ->
        {:error,
         "#{c.name}: no second to judge: the track has #{c.last} s with a true position up to second " <>
           "#{c.truth |> Map.keys() |> Enum.max(fn -> 0 end)}, the warm-up is #{warmup} s"}

      true ->
        :ok
    end
  end

  # The longest stretch of seconds without a reading that a replay walks.
  @max_gap 60

  @doc """
  Shortens the silent stretches of a log: given the seconds that have readings, a map from
  each to its second in the replay (a stretch of more than #{@max_gap} s with no reading
  becomes #{@max_gap} s), and the stretches shortened as `{second, seconds_left_out}` (in
  the replay's seconds).

      iex> {remap, gaps} = TartarusLats.Replay.gaps([1, 2, 3, 10_000_003, 10_000_004])
      iex> {remap[10_000_003], gaps}
      {64, [{3, 9999939}]}
  """
  @spec gaps([pos_integer()]) ::
          {%{pos_integer() => pos_integer()}, [{pos_integer(), pos_integer()}]}
  def gaps(seconds) do
    {remap, gaps, _prev, _shift} =
      seconds
      |> Enum.sort()
      |> Enum.reduce({%{}, [], nil, 0}, fn s, {remap, gaps, prev, shift} ->
        {gaps, shift} =
          if prev != nil and s - prev > @max_gap + 1,
            do:
              {[{prev - shift, s - prev - 1 - @max_gap} | gaps],
               shift + (s - prev - 1 - @max_gap)},
            else: {gaps, shift}

        {Map.put(remap, s, s - shift), gaps, s, shift}
      end)

    {remap, Enum.reverse(gaps)}
  end

  @schema [
    seed: [type: :integer, default: 1, doc: "seed of the query instants and start nodes"],
    queries: [
      type: :pos_integer,
      default: 10,
      doc: "query instants (a Where is X and a Trace each)"
    ],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where the hosts run"],
    group: [type: :pos_integer, default: 6, doc: "nodes per BEAM node (peer mode)"],
    calibration: [type: :any, doc: "a `TartarusLats.Replay.Calibration` (default none)"],
    fingerprints: [
      type: :any,
      default: [],
      doc:
        "the reference points (`TartarusLats.Replay.Calibration.points/2`) for the kNN baseline"
    ],
    window: [type: :pos_integer, default: 4, doc: "the trackers' window and the baselines' (s)"],
    far_m: [type: :number, default: 3.5, doc: "the far threshold's distance under the model (m)"],
    near_m: [type: :number, default: 1.5, doc: "the near threshold's distance (m)"],
    zone: [
      type: :any,
      default: [
        margin_db: 3.0,
        dwell: 2,
        claim_dwell: 1,
        release_on_take: true,
        exit_alone: true,
        one_holder: true
      ],
      doc:
        "options of the nodes' `TartarusLats.Zone` (the defaults here were chosen on the tetam tracks, see docs/lats.md)"
    ],
    k: [type: :pos_integer, default: 3, doc: "neighbours of the kNN baseline"],
    thesis: [
      type: :boolean,
      default: true,
      doc:
        "also run the thesis's own rule (no zone decision: each node's tracker alone, far or near against beyond, drives the motion-vector handshake) as an arm of its own (`:thesis`)"
    ],
    thesis_tracker: [
      type: :keyword_list,
      default: [window: 6, median: 1, confirm: 2, hysteresis_db: 0.0],
      doc:
        "the thesis arm's trackers: the moving average of six (Fig. 3.6), no median, no hysteresis, a change kept once it held two samples (a spike back within a second is not stored)"
    ],
    warmup: [type: :pos_integer, default: 5, doc: "seconds not judged at the start"],
    repair: [
      type: :boolean,
      default: true,
      doc:
        "Where is X and Trace agents bridge a broken chain (`TartarusLats.Query.WhereIs`, `TartarusLats.Query.Trace`, `:repair`; chosen on the tetam tracks, see docs/lats.md)"
    ]
  ]

  @doc "The options of `run/2` (a `Tartarus.Options` schema)."
  @spec schema() :: keyword()
  def schema, do: @schema

  @doc """
  Replays a case (`prepare/3`) into a LATS deployment and judges it. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `%{summary:, seconds:, queries:}`: the summary (per design `lats`, `strongest`,
  `knn`: the rates of `TartarusLats.Replay.Judge.rates/4`, Where is X correct, Trace edit
  distances, cloud connections), one row per second (truth, position and the three
  decisions) and one row per query.
  """
  @spec run(map(), keyword()) :: map()
  def run(c, opts \\ []) do
    opts = Tartarus.Options.validate!(opts, @schema, "TartarusLats.Replay.run/2")
    {decisions, answers, holders} = drive(c, opts, [window: opts[:window]], opts[:zone], :lats)

    thesis =
      if opts[:thesis],
        do: [thesis: drive(c, opts, opts[:thesis_tracker], :tracker, :thesis)],
        else: []

    c
    |> judge(decisions, answers, thesis, opts)
    |> update_in([:summary], &Map.merge(&1, holder_counts(c.building, holders)))
  end

  # One arm's run: a deployment of the case's nodes (the trackers' options `tracker`, the
  # zone decision's `zone`, or `:tracker` for the thesis's own rule) fed second by second;
  # after every second the decision (who holds the tag) is read back, and at the query
  # instants the query agents are released. Returns the decisions, the answers and the
  # nodes that held the tag after every second.
  defp drive(c, opts, tracker, zone, arm) do
    cal = opts[:calibration]
    corrections = Map.new(Building.nodes(c.building), &{&1, Calibration.correction(cal, &1)})
    thresholds = Calibration.thresholds(cal, near_m: opts[:near_m], far_m: opts[:far_m])
    world = World.new(building: c.building, walkers: 0, scripts: [])

    dep =
      Deployment.start(
        world: world,
        feed: c.feed,
        calibration: thresholds,
        corrections: corrections,
        tracker: tracker,
        zone: zone,
        centralized: false,
        mode: opts[:mode],
        group: opts[:group],
        prefix: "lats-replay"
      )

    instants = instants(c.last, opts[:warmup], opts[:queries], opts[:seed])
    rng = :rand.seed_s(:exsss, {opts[:seed], 28, 5})

    try do
      {_dep, decisions, answers, _rng, holders} =
        Enum.reduce(1..c.last//1, {dep, %{}, [], rng, %{}}, fn s, {dep, dec, answers, rng, hs} ->
          dep = Deployment.step(dep)
          {holder, held} = holder(arm, dep, c.tag, s, hs)
          dec = Map.put(dec, s, holder)

          {answers, rng} =
            if s in instants,
              do: ask(dep, c.tag, s, answers, rng, opts[:repair]),
              else: {answers, rng}

          {dep, dec, answers, rng, Map.put(hs, s, held)}
        end)

      {decisions, Enum.reverse(answers), holders}
    after
      Deployment.stop(dep)
    end
  end

  @doc """
  The query instants of a case of `last` seconds: `n` distinct seconds drawn uniformly
  after `warmup` from the seed, sorted (fewer when the case is short).

      iex> TartarusLats.Replay.instants(60, 5, 3, 1) |> length()
      3
  """
  @spec instants(non_neg_integer(), non_neg_integer(), pos_integer(), integer()) :: [
          pos_integer()
        ]
  def instants(last, warmup, n, seed) do
    pool = Enum.to_list((warmup + 1)..last//1)
    rng = :rand.seed_s(:exsss, {seed, 2811, 28})

    {picked, _} =
      Enum.reduce(1..min(n, length(pool))//1, {[], {pool, rng}}, fn _, {acc, {pool, rng}} ->
        {i, rng} = :rand.uniform_s(length(pool), rng)
        {[Enum.at(pool, i - 1) | acc], {List.delete_at(pool, i - 1), rng}}
      end)

    Enum.sort(picked)
  end

  # Which node holds the tag after second `s`, and every node that does. LATS: the one
  # node whose zone decision holds it (when two do, without the one-holder protocol, the
  # one that did not hold it before). The thesis's rule: of the nodes whose tracker hears
  # the tag far or near, the one whose zone it entered last (its presence indicator is the
  # newest), ties by the stronger filtered RSSI, then the name.
  defp holder(arm, dep, tag, s, hs) do
    held =
      for n <- Deployment.live_nodes(dep),
          tag in (Tartarus.store_get(dep.hosts[n], {:lats, :held}) || []),
          do: n

    prev = hs[s - 1] || []

    h =
      case {arm, held} do
        {_, []} ->
          nil

        {_, [one]} ->
          one

        {:lats, many} ->
          Enum.find(many, &(&1 not in prev)) || hd(many)

        {:thesis, many} ->
          Enum.min_by(many, fn n ->
            filtered = Tartarus.store_get(dep.hosts[n], {:lats, :filtered}) || %{}
            {-entered(n, s, hs), -(filtered[tag] || -200), n}
          end)
      end

    {h, held}
  end

  # The first second of node n's current run of holding the tag (it holds it at s).
  defp entered(n, s, hs) do
    if n in (hs[s - 1] || []), do: entered(n, s - 1, hs), else: s
  end

  @doc """
  What the zone decision's holders did over a run, from the nodes that held the tag after
  each second (`%{second => [node]}`): `holders_at_once` (the most nodes that held it after
  one second), `seconds_with_two_holders`, `changes` (the holder changed, seconds held by
  nobody skipped), `non_neighbour_jumps` (of those, from a node to one that is not its
  neighbour) and `non_neighbour_jumps_without_release` (such a jump with no second held by
  nobody in between: what the one-holder protocol rules out).

      iex> b = TartarusLats.Building.custom(positions: %{a: {0, 0, 0}, b: {5, 0, 0}, c: {10, 0, 0}}, adjacency: %{a: [:b], b: [:c]}, entrances: [:a])
      iex> TartarusLats.Replay.holder_counts(b, %{1 => [:a], 2 => [:a, :c], 3 => [:c], 4 => [], 5 => [:a]})
      %{holders_at_once: 2, seconds_with_two_holders: 1, changes: 2, non_neighbour_jumps: 2, non_neighbour_jumps_without_release: 1}
  """
  @spec holder_counts(Building.t(), %{pos_integer() => [atom()]}) :: map()
  def holder_counts(building, holders) do
    seconds = holders |> Enum.sort() |> Enum.map(&elem(&1, 1))

    # The holder of each second (of two, the one that did not hold before), with a marker
    # for the seconds held by nobody.
    {seq, _} =
      Enum.map_reduce(seconds, [], fn held, prev ->
        h =
          case held do
            [] -> :nobody
            [one] -> one
            many -> Enum.find(many, &(&1 not in prev)) || hd(many)
          end

        {h, held}
      end)

    runs = Enum.dedup(seq)

    direct =
      for [a, b] <- Enum.chunk_every(runs, 2, 1, :discard),
          a != :nobody and b != :nobody,
          do: {a, b, :direct}

    released =
      for [a, :nobody, b] <- Enum.chunk_every(runs, 3, 1, :discard),
          a != :nobody and b != :nobody and a != b,
          do: {a, b, :released}

    not_neighbours =
      for {a, b, _} = j <- direct ++ released, b not in Building.neighbours(building, a), do: j

    %{
      holders_at_once: seconds |> Enum.map(&length/1) |> Enum.max(fn -> 0 end),
      seconds_with_two_holders: Enum.count(seconds, &(length(&1) > 1)),
      changes: length(direct) + length(released),
      non_neighbour_jumps: length(not_neighbours),
      non_neighbour_jumps_without_release: Enum.count(not_neighbours, &(elem(&1, 2) == :direct))
    }
  end

  defp ask(dep, tag, s, answers, rng, repair) do
    nodes = Deployment.live_nodes(dep)
    {i, rng} = :rand.uniform_s(length(nodes), rng)
    {j, rng} = :rand.uniform_s(length(nodes), rng)

    new =
      for {type, start} <- [where_is: Enum.at(nodes, i - 1), trace: Enum.at(nodes, j - 1)] do
        {:ok, r} =
          TartarusLats.query(dep.hosts[start], type, tag,
            seed: {:lats_replay, s, type},
            label: "#{type}@#{s}",
            repair: repair
          )

        %{type: type, time: s, start: start, result: r}
      end

    {Enum.reverse(new, answers), rng}
  end

  defp judge(c, lats, answers, arms, opts) do
    window = opts[:window]
    cal = opts[:calibration]

    calibrated =
      Map.new(c.raw, fn {s, by_node} ->
        {s,
         Map.new(by_node, fn {n, r} ->
           {o, sl} = Calibration.correction(cal, n)
           {n, (r - o) / sl}
         end)}
      end)

    # Without reference points there is no fingerprinting baseline.
    knn =
      if opts[:fingerprints] == [],
        do: %{},
        else: %{
          knn:
            Judge.knn(c.raw, Judge.fingerprints(opts[:fingerprints]), c.building,
              last: c.last,
              window: window,
              k: opts[:k]
            )
        }

    # The thesis's own rule, an arm of its own: its decisions, and its query agents' answers
    # at the same instants from the same start nodes.
    thesis = Map.new(arms, fn {arm, {dec, _answers, _held}} -> {arm, dec} end)

    own =
      for {arm, {_dec, arm_answers, _held}} <- arms,
          a <- arm_answers,
          into: %{},
          do: {{arm, a.time, a.type}, a.result}

    designs =
      %{lats: lats, strongest: Judge.strongest(calibrated, c.last, window)}
      |> Map.merge(knn)
      |> Map.merge(thesis)

    judged = (opts[:warmup] + 1)..c.last//1
    stays = Judge.stays(c.truth)

    queries =
      Enum.map(answers, fn q ->
        truth_zones = Judge.zones_until(c.truth, q.time)

        per =
          Map.new(designs, fn {d, dec} ->
            answer =
              case {d, q.type} do
                {:lats, _} -> q.result.answer
                {:thesis, type} -> own[{:thesis, q.time, type}].answer
                {_, :where_is} -> if(dec[q.time], do: {:in_zone, dec[q.time]}, else: :not_found)
                {_, :trace} -> Judge.zones_until(dec, q.time)
              end

            {d, judge_answer(q.type, answer, stays, truth_zones, q.time)}
          end)

        Map.merge(q, %{truth: truth_zones, judged: per, hops: q.result.hops})
      end)

    # A cloud that receives every reading: one connection per receiver per second with
    # readings (uploads batched per second, as the simulated centralized design's).
    central = c.feed |> Map.values() |> Enum.map(&map_size/1) |> Enum.sum()
    contacts = Enum.sum(Enum.map(queries, & &1.result.per_node_contacts))

    thesis_contacts = Enum.sum(for {{:thesis, _, _}, r} <- own, do: r.per_node_contacts)

    summary =
      Map.new(designs, fn {d, dec} ->
        r = Judge.rates(c.building, dec, c.truth, judged)
        wi = for q <- queries, q.type == :where_is, do: q.judged[d].correct
        tr = for q <- queries, q.type == :trace, do: q.judged[d].edit_distance

        {d,
         Map.merge(r, %{
           where_is: length(wi),
           where_is_correct: Enum.count(wi, & &1),
           traces: length(tr),
           trace_edit_mean: TartarusTools.Stats.mean(tr),
           trace_edit_median: TartarusTools.Stats.median(tr),
           trace_exact: Enum.count(tr, &(&1 == 0)),
           cloud_connections:
             case d do
               :lats -> contacts
               :thesis -> thesis_contacts
               _ -> central
             end
         })}
      end)
      |> Map.merge(%{
        track: c.name,
        seconds: c.last,
        seed: opts[:seed],
        mode: opts[:mode],
        repair: opts[:repair],
        window: window,
        far_m: opts[:far_m],
        calibration: if(cal, do: cal.kind, else: :none),
        log_lines: c.lines,
        log_bad_lines: length(c.bad),
        log_gaps_shortened: length(c.gaps),
        unknown_receiver_readings: c.unknown_receivers |> Map.values() |> Enum.sum(),
        unknown_receivers: c.unknown_receivers,
        log_unterminated_line: c.unterminated,
        cloud_connections_lats_per_query:
          Enum.sum(Enum.map(queries, & &1.result.per_query_contacts))
      })

    rows =
      for s <- 1..c.last//1,
          do:
            Map.merge(
              %{second: s, truth: c.truth[s]},
              Map.new(designs, fn {d, dec} -> {d, dec[s]} end)
            )

    %{summary: summary, seconds: rows, queries: queries}
  end

  defp judge_answer(:where_is, answer, stays, _truth_zones, t),
    do: %{answer: answer, correct: TartarusLats.Judge.correct?(:where_is, answer, stays, t)}

  defp judge_answer(:trace, answer, _stays, truth_zones, _t) do
    zones =
      case answer do
        {:ok, %{path: p}} -> Judge.merge(Enum.map(p, & &1.node))
        list when is_list(list) -> list
        _ -> []
      end

    %{answer: zones, edit_distance: Judge.edit_distance(zones, truth_zones)}
  end
end
