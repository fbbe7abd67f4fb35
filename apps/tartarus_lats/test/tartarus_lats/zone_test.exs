defmodule TartarusLats.ZoneTest do
  use ExUnit.Case, async: true
  doctest TartarusLats.Zone

  alias TartarusLats.{Radio, Region, Tracker, Zone}

  @tag_id {"12121212b64445208f0c720eaf059935", 1, 1}
  @cal Region.calibrate(tx_power: -59, exponent: 2.0)

  # Two nodes a and b, 9 m apart (the building's spacing), a tag at `position.(t)` metres
  # from a on the line between them, `seconds` seconds of the radio model with `sigma` dB of
  # noise (spikes and lost packets included). Every second: both trackers take their
  # reading, both nodes report, both decide. Returns the zone events of each second and the
  # trackers' own zone events (the old rule: in the zone whenever the region is not beyond).
  defp run(position, sigma, seed, seconds) do
    radio = Radio.new(noise_sigma: sigma)
    node = fn -> {Tracker.new(calibration: @cal), Zone.new(calibration: @cal)} end
    init = {%{a: node.(), b: node.()}, [], 0, Radio.seed(seed)}

    {_nodes, events, old, _rng} =
      Enum.reduce(1..seconds, init, fn t, {nodes, events, old, rng} ->
        x = position.(t)
        distance = %{a: max(x, 0.3), b: max(9.0 - x, 0.3)}

        {nodes, old, rng} =
          Enum.reduce([:a, :b], {nodes, old, rng}, fn n, {nodes, old, rng} ->
            {v, rng} = Radio.sample(radio, distance[n], -59, rng)
            {tracker, zone} = nodes[n]
            {tev, tracker} = Tracker.observe(tracker, t, @tag_id, v)
            flips = Enum.count(tev, &(elem(&1, 0) in [:entered_zone, :left_zone]))
            {Map.put(nodes, n, {tracker, zone}), old + flips, rng}
          end)

        reports = Map.new(nodes, fn {n, {tracker, zone}} -> {n, Zone.report(zone, tracker)} end)

        {nodes, now} =
          Enum.reduce([a: :b, b: :a], {nodes, []}, fn {n, other}, {nodes, now} ->
            {tracker, zone} = nodes[n]
            {ev, zone} = Zone.decide(zone, t, tracker, %{other => reports[other]})
            {Map.put(nodes, n, {tracker, zone}), now ++ Enum.map(ev, &{t, n, &1})}
          end)

        {nodes, events ++ now, old, rng}
      end)

    {events, old}
  end

  # Zone changes after the first minute (the tag's arrival is not a change).
  defp changes(events), do: Enum.count(events, fn {t, _n, _e} -> t > 60 end)

  test "a tag standing 1 m from a zone boundary for 10 minutes at 4 dB: no zone change (the trackers alone: dozens)" do
    results =
      for seed <- 1..20, x <- [3.5, 5.5] do
        {events, old} = run(fn _ -> x end, 4.0, seed, 660)
        {changes(events), old}
      end

    assert Enum.all?(results, fn {changes, _old} -> changes == 0 end)
    assert results |> Enum.map(&elem(&1, 1)) |> Enum.sum() >= 100
  end

  # The measured bound (docs/lats.md): a tag standing anywhere on the line with up to 4 dB
  # of noise. Over 20,000 random cases: no zone change in 97.3 %, 4-8 events in 95 cases,
  # all within 0.7 m of the boundary, never more than 8 (four hand-overs). 2,000 seeded
  # cases here, the same every run (a random property found the rare tail once in CI).
  # About 30 s alone; more than ExUnit's 60 s on a machine loaded by other work.
  @tag timeout: 300_000
  test "a stationary tag under up to 4 dB of noise, 2,000 seeded cases: no zone change in 95 %, never more than 4 hand-overs in 10 minutes" do
    rng = :rand.seed_s(:exsss, {3, 1, 4})

    {cases, _} =
      Enum.map_reduce(1..2000, rng, fn _, rng ->
        {u1, rng} = :rand.uniform_s(rng)
        {u2, rng} = :rand.uniform_s(rng)
        {seed, rng} = :rand.uniform_s(1_000_000, rng)
        {{0.5 + 8 * u1, 4 * u2, seed}, rng}
      end)

    counts =
      cases
      |> Task.async_stream(
        fn {x, sigma, seed} ->
          {events, _old} = run(fn _ -> x end, sigma, seed, 660)
          {changes(events), x}
        end,
        timeout: :infinity
      )
      |> Enum.map(fn {:ok, r} -> r end)

    assert Enum.count(counts, &(elem(&1, 0) == 0)) >= 1900
    assert Enum.all?(counts, fn {n, _x} -> n <= 8 end)
    # Many changes only near the boundary (4.5 m).
    assert Enum.all?(counts, fn {n, x} -> n <= 2 or abs(x - 4.5) < 1.0 end)
  end

  test "a walker from a to b is handed over once, in one second: a lets go as b takes it" do
    # Still at a for 60 s, then 1.2 m/s to b, then still at b.
    position = fn t -> min(max((t - 60) * 1.2, 1.0), 8.0) end

    for seed <- 1..10 do
      {events, _old} = run(position, 4.0, seed, 120)
      kinds = Enum.map(events, fn {t, n, {kind, _tag, _since}} -> {t, n, kind} end)

      assert [{_, :a, :entered_zone}, {t, :a, :left_zone}, {t, :b, :entered_zone}] = kinds,
             "seed #{seed}: #{inspect(kinds)}"

      # Handed over after the walker passed the midpoint (4.5 m from a, at 63.75 s) and
      # within 8 s of its arrival at b (8 m, at 66.7 s): the filter's lag and the dwell.
      assert t > 64 and t <= 75, "seed #{seed}: handed over at #{t}"
    end
  end

  # A node x between the holder h and the next node n (a corridor h - x - n), one sample a
  # second (window 1): x takes the tag from h for two seconds (8 dB over h), then in the
  # third, the walker past x, x is only 5 dB over h and n hears it 1 dB more strongly.
  defp cut_take(third) do
    z = Zone.new(calibration: @cal, min_heard: 1)
    tracker = Tracker.new(calibration: @cal, window: 1, median: 1, confirm: 1)
    far = z.far_dbm

    first = %{h: %{@tag_id => {far - 3, true, false}}, n: %{@tag_id => {far - 12, false, false}}}

    {[], z, tracker} =
      Enum.reduce([1, 2], {[], z, tracker}, fn t, {[], z, tracker} ->
        {_, tracker} = Tracker.observe(tracker, t, @tag_id, far + 5)
        {events, z} = Zone.decide(z, t, tracker, first)
        {events, z, tracker}
      end)

    {_, tracker} = Tracker.observe(tracker, 3, @tag_id, far + 3)
    {holder, ahead} = third.(far)
    Zone.decide(z, 3, tracker, %{h: %{@tag_id => holder}, n: %{@tag_id => ahead}})
  end

  test "a take cut short because the walker passed on completes, dated from its first second" do
    {events, z} = cut_take(fn far -> {{far - 2, true, false}, {far + 4, false, true}} end)
    assert events == [{:entered_zone, @tag_id, 1}]
    assert Zone.holds?(z, @tag_id)
  end

  test "a take cut short does not complete while the holder hears the tag well, nor without a node ahead hearing it well and as strongly" do
    cases = [
      # the holder still hears it well: the tag may be going back
      fn far -> {{far - 2, true, true}, {far + 4, false, true}} end,
      # the node ahead does not hear it well (a burst lifted its mean, too few samples)
      fn far -> {{far - 2, true, false}, {far + 4, false, false}} end,
      # the node ahead is weaker than this one: the walker has not passed on
      fn far -> {{far - 2, true, false}, {far + 2, false, true}} end,
      # this node is not 1 dB nearer than the holder
      fn far -> {{far + 2.5, true, false}, {far + 4, false, true}} end
    ]

    for third <- cases do
      {events, z} = cut_take(third)
      assert events == []
      refute Zone.holds?(z, @tag_id)
    end
  end

  test "a holder lets go at once to a neighbour that holds the tag too and hears it 1 dB more strongly" do
    z = Zone.new(calibration: @cal, min_heard: 1, claim_dwell: 1)
    tracker = Tracker.new(calibration: @cal, window: 1, median: 1, confirm: 1)
    far = z.far_dbm
    {_, tracker} = Tracker.observe(tracker, 1, @tag_id, far + 5)
    {[{:entered_zone, _, 1}], z} = Zone.decide(z, 1, tracker, %{})
    {_, tracker} = Tracker.observe(tracker, 2, @tag_id, far - 6)

    assert {[], _} = Zone.decide(z, 2, tracker, %{x: %{@tag_id => {far - 5.5, true, false}}})

    assert {[{:left_zone, @tag_id, 2}], z} =
             Zone.decide(z, 2, tracker, %{x: %{@tag_id => {far - 4, true, false}}})

    refute Zone.holds?(z, @tag_id)
  end

  # A node that holds the tag (heard at `own` dBm from second 2 on) and one neighbour x
  # reporting `x_report` every second; the events of seconds 2..`last`.
  defp held_then(opts, own, x_report, last) do
    z = Zone.new([calibration: @cal, min_heard: 1, claim_dwell: 1, dwell: 2] ++ opts)
    tracker = Tracker.new(calibration: @cal, window: 1, median: 1, confirm: 1)
    {_, tracker} = Tracker.observe(tracker, 1, @tag_id, z.far_dbm + 5)
    {[{:entered_zone, _, 1}], z} = Zone.decide(z, 1, tracker, %{})

    Enum.reduce(2..last, {[], z}, fn t, {events, z} ->
      {_, tracker} = Tracker.observe(tracker, t, @tag_id, own)
      {ev, z} = Zone.decide(z, t, tracker, %{x: %{@tag_id => x_report}})
      {events ++ ev, z}
    end)
  end

  test "release_on_take: the holder keeps a tag a stronger neighbour does not take, and lets go once it has" do
    far = Zone.new(calibration: @cal).far_dbm
    stronger = {far + 8, false, true}

    # By default a neighbour 7 dB stronger for 2 s takes it: the holder lets go...
    assert {[{:left_zone, @tag_id, 2}], z} = held_then([], far + 1, stronger, 4)
    refute Zone.holds?(z, @tag_id)

    # ...with release_on_take it keeps it while the neighbour has not taken it,
    assert {[], z} = held_then([release_on_take: true], far + 1, stronger, 8)
    assert Zone.holds?(z, @tag_id)

    # and lets go at once when the neighbour holds it, more strongly.
    assert {[{:left_zone, @tag_id, 2}], z} =
             held_then([release_on_take: true], far + 1, {far + 8, true, true}, 4)

    refute Zone.holds?(z, @tag_id)
  end

  test "exit_alone: a tag out of range of its holder stays held while a neighbour still hears it" do
    z = Zone.new(calibration: @cal)
    gone = z.exit_dbm - 6
    # The neighbour hears it, but not well enough to take it (under the far threshold).
    heard_there = {z.exit_dbm + 1, false, false}
    unheard = {z.missing_rssi, false, false}

    assert {[{:left_zone, @tag_id, 2}], _} = held_then([], gone, heard_there, 8)
    assert {[], z1} = held_then([exit_alone: true], gone, heard_there, 12)
    assert Zone.holds?(z1, @tag_id)
    assert {[{:left_zone, @tag_id, 2}], _} = held_then([exit_alone: true], gone, unheard, 8)
  end

  test "bad options are refused naming the key" do
    assert_raise ArgumentError, ~r/for key :dwell/, fn -> Zone.new(dwell: 0) end

    assert_raise ArgumentError, ~r/claim_db <= margin_db <= fast_db/, fn ->
      Zone.new(margin_db: 20)
    end
  end
end
