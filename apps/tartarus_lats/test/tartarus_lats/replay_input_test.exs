defmodule TartarusLats.ReplayInputTest do
  # The real-data replay's inputs and judge, pure: the log parser (malformed lines counted
  # and skipped with their line number), devices, the Delaunay floor plan, calibration, the
  # baselines and the measures.
  use ExUnit.Case, async: true
  doctest TartarusLats.Replay.Log
  doctest TartarusLats.Replay.Devices
  doctest TartarusLats.Replay.Calibration
  doctest TartarusLats.Replay.Judge
  doctest TartarusLats.Replay
  doctest TartarusLats.Replay.Splits

  test "out of sample: six splits of four tracks, each judged on the two it was not chosen on" do
    fig = fn held, exact ->
      %{pass: %{a: held > 0, b: held > 1}, lats: %{exact: exact, adjacent: 1.0}}
    end

    names = ["s1", "s2", "s3", "r"]
    # Configuration 0 is best on s1 and s2, configuration 1 on the others.
    results = [
      {[c: 0],
       Map.new(names, &{&1, if(&1 in ["s1", "s2"], do: fig.(2, 0.9), else: fig.(0, 0.1))})},
      {[c: 1],
       Map.new(names, &{&1, if(&1 in ["s1", "s2"], do: fig.(0, 0.1), else: fig.(2, 0.9))})}
    ]

    splits = TartarusLats.Replay.Splits.splits(results, names)
    assert length(splits) == 6

    for s <- splits do
      assert MapSet.disjoint?(MapSet.new(s.tuning), MapSet.new(s.judged))
      assert Enum.sort(s.tuning ++ s.judged) == Enum.sort(names)
      assert Map.keys(s.out_of_sample) |> Enum.sort() == Enum.sort(s.judged)
    end

    # Chosen on s1 and s2: configuration 0, judged on r and s3 where it is the worse one.
    assert %{config: [c: 0], out_of_sample: %{"r" => %{lats: %{exact: 0.1}}}} =
             Enum.find(splits, &(&1.tuning == ["s1", "s2"]))

    assert length(TartarusLats.Replay.Splits.grid()) == 18
  end

  alias TartarusLats.{Building, Tracker}
  alias TartarusLats.Replay.{Calibration, Devices, Judge, Log}

  @devices Path.expand("../fixtures/tetam.dev", __DIR__)

  describe "the log parser" do
    test "every kind of malformed line is skipped and counted with its line number" do
      text = """
      # a comment
      time,receiver,beacon,rssi,x,y
      100.0,r1,aa,-70,1.0,2.0
      100.1,r1,aa
      abc,r1,aa,-70
      100.2,r1,aa,loud
      100.3,r1,aa,-300
      100.4,r1,aa,5
      100.5,,aa,-70
      100.6,r1,,-70

      100.7,r1,aa,-70,1.0
      100.8,r1,aa,-70,x,2.0
      100.9,r2,AA,-71,3.0,4.0,1.8,0.1,0.2
      """

      log = Log.parse(text)

      assert Enum.map(log.readings, &{&1.line, &1.receiver, &1.beacon, &1.pos}) ==
               [{3, "r1", "aa", {1.0, 2.0}}, {14, "r2", "aa", {3.0, 4.0}}]

      assert log.bad == [
               {4, "expected time, receiver, beacon, rssi[, x, y], got 3 fields"},
               {5, "time is not a number: \"abc\""},
               {6, "rssi is not a number: \"loud\""},
               {7, "rssi out of range (-127..0): -300"},
               {8, "rssi out of range (-127..0): 5"},
               {9, "empty receiver"},
               {10, "empty beacon"},
               {12, "x without y"},
               {13, "x is not a number: \"x\""}
             ]

      assert log.lines == 11
    end

    test "random bytes and random lines never raise; every line is either read or counted" do
      rng = :rand.seed_s(:exsss, {28, 1, 1})

      Enum.reduce(1..200, rng, fn _, rng ->
        {n, rng} = :rand.uniform_s(40, rng)
        {bytes, rng} = :rand.bytes_s(n, rng)
        {k, rng} = :rand.uniform_s(4, rng)
        pieces = ["1.0", "r1", "aa", "-70", "", ",", "x", bytes, "2.5", "-0"]

        {line, rng} =
          Enum.reduce(1..(k + 3), {"", rng}, fn _, {acc, rng} ->
            {i, rng} = :rand.uniform_s(length(pieces), rng)
            {acc <> "," <> Enum.at(pieces, i - 1), rng}
          end)

        text = bytes <> "\n" <> String.trim_leading(line, ",")
        log = Log.parse(text)
        assert length(log.readings) + length(log.bad) == log.lines
        rng
      end)
    end

    test "readings are grouped per receiver and second (mean, rounded), positions per second" do
      log =
        Log.parse("10.2,r1,aa,-70,1,1\n10.9,r1,aa,-75,2,2\n11.5,r1,aa,-80,3,3\n12.1,r2,bb,-60\n")

      {t0, per} = Log.per_second(log)
      assert t0 == 10.0

      assert per == %{
               1 => %{"r1" => %{"aa" => -73}},
               2 => %{"r1" => %{"aa" => -80}},
               3 => %{"r2" => %{"bb" => -60}}
             }

      assert Log.positions(log, t0, "aa") == %{1 => {2.0, 2.0}, 2 => {3.0, 3.0}}
      assert Log.beacons(log) == ["aa", "bb"]
    end

    test "the fixture (25 s of a tetam track) parses without a bad line" do
      log = Log.read!(Path.expand("../fixtures/tetam_straight_01_25s.csv", __DIR__))
      assert log.bad == []
      assert length(log.readings) > 500
    end
  end

  describe "devices and the floor plan" do
    test "the tetam devices file: twelve receivers by their aliases" do
      d = Devices.read!(@devices)
      assert map_size(d) == 12
      assert d["b827eb4521b4"] == %{name: :sensor10, pos: {7.0, 7.09, 1.22}}
    end

    test "a malformed CSV devices file names its line" do
      assert_raise ArgumentError, ~r/devices:2: x, y, z must be numbers/, fn ->
        Devices.parse!("aa,0,0,1\nbb,x,0,1")
      end
    end

    test "the Delaunay graph of a grid joins the grid's neighbours, and every true zone change is between neighbours" do
      pts = for r <- 0..2, c <- 0..2, into: %{}, do: {:"n#{r}#{c}", {c * 5.0, r * 4.0}}
      edges = Devices.delaunay(pts)
      for r <- 0..2, c <- 0..1, do: assert({:"n#{r}#{c}", :"n#{r}#{c + 1}"} in edges)
      for r <- 0..1, c <- 0..2, do: assert({:"n#{r}#{c}", :"n#{r + 1}#{c}"} in edges)

      # A walk across the tetam office: consecutive true zones are equal or neighbours.
      b = Devices.building(Devices.read!(@devices))

      truth =
        for i <- 0..400 do
          t = i / 400
          Judge.nearest(b, {1.0 + 17.0 * t, 1.0 + 15.0 * :math.sin(t * 3)})
        end

      for [a, z] <- Enum.chunk_every(Enum.dedup(truth), 2, 1, :discard),
          do: assert(z in Building.neighbours(b, a))
    end

    test "a floor plan written and read back is the same building" do
      b = Devices.building(Devices.read!(@devices))
      b2 = Devices.parse_floor_plan!(Devices.floor_plan(b))
      assert Building.nodes(b2) == Building.nodes(b)
      assert Building.adjacency(b2) == Building.adjacency(b)
      assert Building.entrances(b2) == Building.entrances(b)
      assert_raise ArgumentError, ~r/floor plan:1/, fn -> Devices.parse_floor_plan!("nope") end
    end
  end

  describe "calibration" do
    @tag :tmp_dir
    test "offset and slope corrections recover a receiver's bias; the file reads back", %{
      tmp_dir: dir
    } do
      pts =
        for {node, a, b} <- [{:a, 4.0, 1.0}, {:b, -3.0, 1.0}, {:c, 0.0, 1.2}],
            d <- [1.0, 2.0, 3.0, 5.0, 8.0],
            do: %{node: node, distance: d, mean: a + b * (-60 - 20 * :math.log10(d))}

      cal = Calibration.fit(pts, :slope)
      # c's path-loss slope is 1.2 times the others': its correction says so.
      assert_in_delta cal.receivers.c.slope / cal.receivers.a.slope, 1.2, 0.01
      assert cal.receivers.a.rms_corrected_db < 0.5
      off = Calibration.fit(pts, :offset)
      assert off.receivers.a.offset > off.receivers.b.offset + 6

      path = Path.join(dir, "cal.json")
      Calibration.write!(path, cal)
      back = Calibration.read!(path)
      assert back.kind == :slope
      assert_in_delta elem(Calibration.correction(back, :c), 1), cal.receivers.c.slope, 1.0e-9
      assert Calibration.correction(back, :unknown) == {0.0, 1.0}
    end

    test "the tracker applies its node's correction to every sample" do
      tag = {"00000000000000000000000000000001", 0, 0}
      t = Tracker.new(window: 2, median: 1, correction: {5.0, 1.0})
      {_, t} = Tracker.observe(t, 1, tag, -70)
      {_, t} = Tracker.observe(t, 2, tag, -70)
      assert Tracker.heard_average(t, tag) == -75.0

      assert_raise ArgumentError, ~r/:correction/, fn ->
        Tracker.new(correction: {0.0, 0.0})
      end
    end
  end

  describe "baselines and measures" do
    test "fingerprinting picks the receiver nearest the nearest reference points" do
      b =
        Building.custom(
          positions: %{a: {0, 0, 0}, b: {10, 0, 0}},
          adjacency: %{a: [:b]},
          entrances: [:a]
        )

      fps =
        Judge.fingerprints([
          %{node: :a, pos: {1.0, 0.0, 1.0}, mean: -60.0},
          %{node: :b, pos: {1.0, 0.0, 1.0}, mean: -80.0},
          %{node: :a, pos: {9.0, 0.0, 1.0}, mean: -80.0},
          %{node: :b, pos: {9.0, 0.0, 1.0}, mean: -60.0}
        ])

      feed = %{1 => %{a: -62, b: -79}, 2 => %{a: -81, b: -61}, 3 => %{a: -81, b: -61}}
      assert Judge.knn(feed, fps, b, last: 3, window: 1, k: 1) == %{1 => :a, 2 => :b, 3 => :b}
    end

    test "stays and zones of the truth" do
      truth = %{1 => :a, 2 => :a, 3 => :b, 4 => :a}

      assert Judge.stays(truth) == [
               %{zone: :a, entered_at: 1, left_at: 3},
               %{zone: :b, entered_at: 3, left_at: 4},
               %{zone: :a, entered_at: 4, left_at: nil}
             ]

      assert Judge.zones_until(truth, 3) == [:a, :b]
      assert TartarusLats.Judge.correct?(:where_is, {:in_zone, :b}, Judge.stays(truth), 4)
      refute TartarusLats.Judge.correct?(:where_is, {:in_zone, :c}, Judge.stays(truth), 4)
      assert Judge.edit_distance([], [:a, :b]) == 2
      assert Judge.edit_distance([:a, :b], [:a, :b]) == 0
    end
  end
end
