defmodule TartarusLats.TrackerTest do
  use ExUnit.Case, async: true
  doctest TartarusLats.Tracker

  alias TartarusLats.{Region, Tracker}

  @tag_id {"12121212b64445208f0c720eaf059935", 1234, 1111}

  defp feed(tracker, samples, t0 \\ 1) do
    samples
    |> Enum.with_index(t0)
    |> Enum.reduce({[], tracker}, fn {rssi, t}, {acc, tr} ->
      {events, tr} = Tracker.observe(tr, t, @tag_id, rssi)
      {acc ++ events, tr}
    end)
  end

  defp records(events), do: for({:record, r} <- events, do: {r.time, r.region})

  test "writes a record only when the region changes" do
    tr = Tracker.new()
    {events, tr} = feed(tr, List.duplicate(-60, 20))
    assert [{_, :near}] = records(events)
    assert {:entered_zone, @tag_id, _} = List.keyfind(events, :entered_zone, 0)
    assert Tracker.region(tr, @tag_id) == :near

    {events, tr} = feed(tr, List.duplicate(-70, 20), 21)
    assert [{_, :far}] = records(events)
    refute List.keyfind(events, :left_zone, 0)

    {events, _tr} = feed(tr, List.duplicate(:missing, 20), 41)
    assert [{_, :beyond}] = records(events)
    assert {:left_zone, @tag_id, t} = List.keyfind(events, :left_zone, 0)
    assert t > 41
  end

  test "the record carries time, identity, rssi and region of the first sample of the change" do
    {events, _} = feed(Tracker.new(window: 1, median: 1), [-100, -100, -70, -70, -70])

    assert [
             {:record,
              %{
                time: 3,
                uuid: "12121212b64445208f0c720eaf059935",
                major: 1234,
                minor: 1111,
                rssi: -70,
                region: :far
              }},
             {:entered_zone, @tag_id, 3}
           ] = events
  end

  test "a spike beyond -> far -> beyond within a second writes nothing" do
    # Raw classification (no median, window 1): only the debounce protects.
    raw = Tracker.new(window: 1, median: 1)
    assert {[], _} = feed(raw, [:missing, :missing, -68, :missing, :missing])

    # Default pipeline, tag just beyond 5 m (-75 dBm) and one strong spike.
    assert {[], _} =
             feed(Tracker.new(), List.duplicate(-75, 8) ++ [-50] ++ List.duplicate(-75, 8))
  end

  test "a change that holds two samples is recorded" do
    raw = Tracker.new(window: 1, median: 1)
    {events, _} = feed(raw, [:missing, -68, -68, :missing, :missing])
    assert [{2, :far}, {4, :beyond}] = records(events)
  end

  test "tick treats known tags absent from the readings as missing and forgets them" do
    tr = Tracker.new()

    {_, tr} =
      Enum.reduce(1..10, {[], tr}, fn t, {_, tr} -> Tracker.tick(tr, t, %{@tag_id => -62}) end)

    assert Tracker.present(tr) == [@tag_id]
    {_, tr} = Enum.reduce(11..30, {[], tr}, fn t, {_, tr} -> Tracker.tick(tr, t, %{}) end)
    assert Tracker.tags(tr) == []
    assert Tracker.region(tr, @tag_id) == :beyond
  end

  test "uses the calibration given" do
    tr = Tracker.new(calibration: Region.calibration(-50, -55), window: 1, median: 1)
    {events, _} = feed(tr, [-60, -60, -60])
    assert events == []
  end

  test "bad input raises with a clear message" do
    assert_raise ArgumentError, ~r/:median/, fn -> Tracker.new(median: 2) end

    assert_raise ArgumentError, ~r/invalid sample/, fn ->
      Tracker.observe(Tracker.new(), 1, @tag_id, "x")
    end
  end

  # A tag standing 5.5 m from a node (1 m into the neighbouring zone, zones 9 m apart), where
  # its average hovers 0.8 dB under the far threshold, with the default radio (2 dB noise,
  # spikes, drops): hysteresis keeps the node from logging far/beyond flips.
  test "a stationary tag near a zone boundary: at most 4 records in 10 minutes (without hysteresis: dozens)" do
    cal = Region.calibrate(tx_power: -59, exponent: 2.0)

    records = fn h, seed ->
      1..600
      |> Enum.reduce(
        {Tracker.new(calibration: cal, hysteresis_db: h), 0, TartarusLats.Radio.seed(seed)},
        fn t, {tr, n, rng} ->
          {v, rng} = TartarusLats.Radio.sample(%TartarusLats.Radio{}, 5.5, -59, rng)
          {events, tr} = Tracker.observe(tr, t, @tag_id, v)
          {tr, n + Enum.count(events, &match?({:record, _}, &1)), rng}
        end
      )
      |> elem(1)
    end

    with_h = for seed <- 1..20, do: records.(1.5, seed)
    without = for seed <- 1..20, do: records.(0, seed)
    assert Enum.max(with_h) <= 4
    assert Enum.sum(with_h) * 10 <= Enum.sum(without)
    assert Enum.min(without) >= 20
  end
end
