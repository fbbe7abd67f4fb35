defmodule TartarusLats.WhereIsRepairTest do
  # Where is X with `repair: true` (issue 28, item 5, Where is X only): a chain of motion
  # vectors broken because the tag turned up in a zone that is not a neighbour of the zone
  # that held it (it claimed the tag from nowhere, the old holder let it go to nobody).
  use ExUnit.Case, async: false

  alias TartarusLats.{Building, Deployment, Region, World}
  alias TartarusLats.Replay
  alias TartarusLats.Replay.{Devices, Log}

  # a - b - c in a row, e above b: a and c are not Delaunay neighbours.
  @devices "ra,0,0,1,a\nrb,5,0,1,b\nrc,10,0,1,c\nre,5,5,1,e\n"

  defp log(jump_at, last) do
    for s <- 1..last, rx <- ~w(ra rb rc re), half <- [0.0, 0.5] do
      at = if s < jump_at, do: "ra", else: "rc"
      rssi = if rx == at, do: -55, else: -85
      {x, y} = if s < jump_at, do: {0.5, 0.0}, else: {9.5, 0.0}
      "#{1000 + s + half},#{rx},e78f135624ce,#{rssi},#{x},#{y}"
    end
    |> Log.parse()
  end

  @tag timeout: 120_000
  test "a tag that turns up two zones away: Where is X from the old zone bridges the gap" do
    devices = Devices.parse!(@devices)
    c = Replay.prepare(log(21, 60), devices)
    refute :c in Building.neighbours(c.building, :a)

    dep =
      Deployment.start(
        world: World.new(building: c.building, walkers: 0, scripts: []),
        feed: c.feed,
        calibration: Region.calibrate(near_m: 1.5, far_m: 3.5),
        centralized: false,
        prefix: "repair-test"
      )

    try do
      dep = Deployment.run(dep, 55)
      # The zone decision holds the tag at c; a's chain ends in an exit nobody acknowledged.
      assert Tartarus.store_get(dep.hosts[:c], {:lats, :held}) == [c.tag]
      assert Tartarus.store_get(dep.hosts[:a], {:lats, :held}) == []

      {:ok, plain} = TartarusLats.query(dep.hosts[:a], :where_is, c.tag)
      assert plain.answer == :left_building
      assert plain.bridges == []

      {:ok, repaired} = TartarusLats.query(dep.hosts[:a], :where_is, c.tag, repair: true)
      assert repaired.answer == {:in_zone, :c}
      assert [%{from: :a, to: :c}] = repaired.bridges

      # Nothing to bridge where the chain is whole: asked at c, the same answer, no bridge.
      {:ok, at_c} = TartarusLats.query(dep.hosts[:c], :where_is, c.tag, repair: true)
      assert at_c.answer == {:in_zone, :c} and at_c.bridges == []
    after
      Deployment.stop(dep)
    end
  end

  @tag timeout: 120_000
  test "a tag that really left: the bridge finds no later stay and the answer stands" do
    devices = Devices.parse!(@devices)
    # At a for 20 s, then heard by nobody.
    lines =
      for s <- 1..20, half <- [0.0, 0.5], do: "#{1000 + s + half},ra,e78f135624ce,-55,0.5,0.0"

    c =
      Replay.prepare(Log.parse(lines ++ ["1060.0,rb,ffffffffffff,-90"]), devices,
        beacon: "e78f135624ce"
      )

    dep =
      Deployment.start(
        world: World.new(building: c.building, walkers: 0, scripts: []),
        feed: c.feed,
        calibration: Region.calibrate(near_m: 1.5, far_m: 3.5),
        centralized: false,
        prefix: "repair-test2"
      )

    try do
      dep = Deployment.run(dep, 55)
      {:ok, r} = TartarusLats.query(dep.hosts[:c], :where_is, c.tag, repair: true)
      assert r.answer == :left_building
      assert r.bridges == []
      # It asked every node within two rings of a before answering.
      assert Enum.sort(Enum.uniq(r.route)) == [:a, :b, :c, :e]
    after
      Deployment.stop(dep)
    end
  end
end
