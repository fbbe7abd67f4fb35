defmodule TartarusLats.WorldTest do
  use ExUnit.Case, async: true
  doctest TartarusLats.Radio
  doctest TartarusLats.Building
  doctest TartarusLats.World

  alias TartarusLats.{Building, MotionVectors, Radio, Sim, World}

  describe "Radio" do
    test "deterministic by seed, different across seeds" do
      radio = Radio.new()

      draw = fn seed ->
        Enum.map_reduce(1..50, Radio.seed(seed), fn _, r -> Radio.sample(radio, 4.0, -59, r) end)
        |> elem(0)
      end

      assert draw.(1) == draw.(1)
      refute draw.(1) == draw.(2)
    end

    test "the mean follows the log-distance model" do
      radio = Radio.new(spike_probability: 0.0, drop_probability: 0.0)

      {samples, _} =
        Enum.map_reduce(1..2000, Radio.seed(3), fn _, r -> Radio.sample(radio, 5.0, -59, r) end)

      mean = Enum.sum(samples) / length(samples)
      assert_in_delta mean, Radio.mean_rssi(5.0, -59, 2.0), 0.3
    end

    test "spikes happen at the configured rate" do
      radio = Radio.new(noise_sigma: 0.0, spike_probability: 0.2, drop_probability: 0.0)

      {samples, _} =
        Enum.map_reduce(1..2000, Radio.seed(4), fn _, r -> Radio.sample(radio, 10.0, -59, r) end)

      rate = Enum.count(samples, &(&1 > -75)) / 2000
      assert_in_delta rate, 0.2, 0.04
    end

    test "bad options" do
      assert_raise ArgumentError, ~r/:spike_probability/, fn ->
        Radio.new(spike_probability: 2)
      end

      assert_raise ArgumentError, ~r/unknown key :foo/, fn -> Radio.new(foo: 1) end
    end
  end

  describe "Building" do
    test "default: 50 nodes, 2 floors, symmetric adjacency, stairs" do
      b = Building.new()
      assert length(Building.nodes(b)) == 50

      for {n, ns} <- Building.adjacency(b), m <- ns do
        assert n in Building.neighbours(b, m)
      end

      assert :p26 in Building.neighbours(b, :p1)
      assert :p50 in Building.neighbours(b, :p25)
      refute :p27 in Building.neighbours(b, :p2)
      assert length(Building.shortest_path(b, :p3, :p38)) > 2
    end

    test "configurable size" do
      b = Building.new(floors: 3, rows: 4, cols: 6)
      assert length(Building.nodes(b)) == 72
      assert Building.position(b, :p72) == {45.0, 27.0, 8.0}
    end
  end

  describe "World" do
    test "10 bearers, 4 scripted, ground truth paths are contiguous and adjacent" do
      world = World.new()
      assert length(World.names(world)) == 10

      {world, _} =
        Enum.reduce(1..1500, {world, Radio.seed(5)}, fn _, {w, r} -> World.step(w, r) end)

      for name <- World.names(world) do
        path = World.visited_path(world, name)
        assert path != []

        for [a, b] <- Enum.chunk_every(path, 2, 1, :discard) do
          assert a.left_at == b.entered_at
          assert b.zone in Building.neighbours(world.building, a.zone)
        end
      end

      assert World.current_zone(world, :head) == :outside
      assert List.last(World.visited_path(world, :head)).left_at != nil
      assert hd(World.visited_path(world, :head)).zone == :p3
    end

    test "readings: the bearer's own node hears it strongest" do
      world =
        Enum.reduce(1..40, World.new(), fn _, w -> elem(World.step(w, Radio.seed(1)), 0) end)

      {readings, _} = World.readings(world, Radio.seed(9))
      tag = World.tag(world, :janitor)
      zone = World.current_zone(world, :janitor)
      heard = for {node, r} <- readings, is_integer(r[tag]), do: {node, r[tag]}
      assert {^zone, _} = Enum.max_by(heard, &elem(&1, 1))
    end
  end

  describe "Sim (pure end-to-end)" do
    @tag timeout: 120_000
    test "traces reconstructed from motion vectors match ground truth" do
      sim = Sim.new(seed: 2) |> Sim.run(1800)
      stats = Sim.stats(sim)
      assert stats.argmax > 0.8
      assert stats.false_presence < 0.01

      for name <- World.names(sim.world) do
        truth = Enum.map(World.visited_path(sim.world, name), & &1.zone)
        tag = World.tag(sim.world, name)
        assert {:ok, trace} = MotionVectors.trace(sim.tables, List.last(truth), tag)
        got = Enum.map(trace.path, & &1.node)
        # the trackers lag the ground truth by a few seconds
        assert got in [truth, Enum.drop(truth, -1)],
               "#{name}: #{inspect(got)} vs #{inspect(truth)}"
      end

      for name <- [:head, :professor, :janitor, :guard] do
        tag = World.tag(sim.world, name)

        assert {:ok, %{status: :exited, entry: :infinity}} =
                 MotionVectors.trace(sim.tables, :p3, tag)
      end
    end

    test "each node's log only holds region changes" do
      sim = Sim.new(seed: 1) |> Sim.run(300)

      for node <- Building.nodes(sim.world.building) do
        sim
        |> Sim.log(node)
        |> Enum.group_by(&{&1.uuid, &1.major, &1.minor})
        |> Enum.each(fn {_tag, rows} ->
          regions = Enum.map(rows, & &1.region)
          assert regions == Enum.dedup(regions)
        end)
      end
    end
  end
end
