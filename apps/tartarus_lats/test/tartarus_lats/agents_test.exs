defmodule TartarusLats.AgentsTest do
  use ExUnit.Case, async: false
  doctest TartarusLats.Query

  alias TartarusLats.{Building, Cloud, Deployment, MotionVectors, World}

  # The thesis's Appendix .2 (see test/support/appendix.ex).
  defp appendix_world, do: TartarusLats.Test.Appendix.world()

  defp nodes(path), do: Enum.map(path, & &1.node)

  setup_all do
    dep =
      Deployment.start(seed: 1, world: appendix_world(), prefix: "appx") |> Deployment.run(150)

    on_exit(fn -> Deployment.stop(dep) end)
    %{dep: dep, tag: World.tag(dep.world, :x)}
  end

  test "ground truth of the Appendix .2 walk", %{dep: dep} do
    assert Enum.map(World.visited_path(dep.world, :x), & &1.zone) == [:d, :e, :f, :i, :h]
  end

  test "Trace(X) fired at a searches conscientiously, then follows the vectors", %{
    dep: dep,
    tag: tag
  } do
    assert {:ok, r} = TartarusLats.query(dep.hosts[:a], :trace, tag, seed: 3)
    assert {:ok, %{path: path, entry: :infinity, status: :present}} = r.answer
    assert nodes(path) == [:d, :e, :f, :i, :h]
    # entry/exit times within a few seconds of the truth
    for {p, t} <- Enum.zip(path, World.visited_path(dep.world, :x)),
        do: assert(abs(p.arrived_at - t.entered_at) <= 8)

    assert hd(r.route) == :a
    assert Enum.take(r.route, -5) == [:d, :e, :f, :i, :h]
    assert r.hops == length(r.route) - 1
  end

  test "a Trace that walks back to an entry from outside on a node with no door says its chain is broken there (entry :gap, not complete)",
       %{dep: dep, tag: tag} do
    assert Tartarus.store_get(dep.hosts[:d], {:lats, :entrance}) == true
    assert Tartarus.store_get(dep.hosts[:e], {:lats, :entrance}) == false

    assert {:ok, %{answer: {:ok, %{entry: :infinity}}, complete: true}} =
             TartarusLats.query(dep.hosts[:h], :trace, tag, report: false)

    # d without its door: X's first stay "came from outside" where nobody can come in, so
    # a hand-over before it was lost (what a missed hand-over or a dead node's zone leaves).
    :ok = Tartarus.store_put(dep.hosts[:d], {:lats, :entrance}, false)

    try do
      assert {:ok,
              %{answer: {:ok, %{entry: :gap, path: path, status: :present}}, complete: false}} =
               TartarusLats.query(dep.hosts[:h], :trace, tag, report: false)

      assert nodes(path) == [:d, :e, :f, :i, :h]
    after
      :ok = Tartarus.store_put(dep.hosts[:d], {:lats, :entrance}, true)
    end
  end

  test "a scripted bearer comes in through a door of the building" do
    b =
      Building.custom(
        positions: %{a: {0, 0, 0}, b: {9, 0, 0}},
        adjacency: %{a: [:b]},
        entrances: [:a]
      )

    script = %{name: :z, enter_at: 0, entrance: :b, route: [{:b, 10}], exit: :a}

    assert_raise ArgumentError,
                 ~r/entrance to be one of the building's entrances \[:a\], got: :b/,
                 fn ->
                   World.new(building: b, walkers: 0, scripts: [script])
                 end
  end

  test "Trace(X) fired at e goes back to d, then forward (Appendix .2)", %{dep: dep, tag: tag} do
    assert {:ok, r} = TartarusLats.query(dep.hosts[:e], :trace, tag)
    assert r.route == [:e, :d, :e, :f, :i, :h]
    assert {:ok, %{path: path, status: :present}} = r.answer
    assert nodes(path) == [:d, :e, :f, :i, :h]
  end

  test "Trace(X) fired where X is walks back only (Algorithm 1, first branch)", %{
    dep: dep,
    tag: tag
  } do
    assert {:ok, r} = TartarusLats.query(dep.hosts[:h], :trace, tag)
    assert r.route == [:h, :i, :f, :e, :d]
    assert {:ok, %{path: path}} = r.answer
    assert nodes(path) == [:d, :e, :f, :i, :h]
  end

  test "Where is X follows MVF; Where am I from a neighbour", %{dep: dep, tag: tag} do
    assert {:ok, %{answer: {:in_zone, :h}, route: route}} =
             TartarusLats.query(dep.hosts[:d], :where_is, tag)

    assert route == [:d, :e, :f, :i, :h]

    assert {:ok, %{answer: {:in_zone, :h}, hops: 1}} =
             TartarusLats.query(dep.hosts[:i], :where_am_i, tag)
  end

  test "an unknown tag is not found once the network is exhausted", %{dep: dep} do
    assert {:ok, r} = TartarusLats.query(dep.hosts[:a], :where_is, {"00", 9, 9}, report: false)
    assert r.answer == :not_found
    assert Enum.sort(Enum.uniq(r.route)) == Building.nodes(dep.building)
    assert {:ok, %{answer: :not_found}} = TartarusLats.query(dep.hosts[:j], :trace, {"00", 9, 9})
  end

  test "many queries at once, and the cloud answers the same centrally", %{dep: dep, tag: tag} do
    ids =
      for n <- [:a, :b, :c, :g, :j], type <- [:where_is, :trace] do
        {:ok, id} = TartarusLats.release(dep.hosts[n], type, tag, report: false)
        {type, id}
      end

    for {type, id} <- ids do
      assert {:ok, r} = TartarusLats.await(id)
      central = Cloud.query(dep.cloud, type, :a, tag)
      assert r.answer == central
    end

    stats = Cloud.stats(dep.cloud)
    assert stats.connections.centralized > 10
    assert stats.bytes.centralized > 0
  end

  test "a query written at run time is released like the built-in ones", %{dep: dep, tag: tag} do
    {:ok, [mod]} =
      Tartarus.compile_string("""
      defmodule TartarusLats.AgentsTest.Census do
        use Tartarus.Agent
        def init(n), do: visit(%{left: n, seen: %{}})
        def handle_arrival(_ctx, s), do: visit(s)

        defp visit(s) do
          mv = Tartarus.Agent.store_get({:lats, :mv})
          node = Tartarus.Agent.store_get({:lats, :node})
          s = %{s | seen: Map.put(s.seen, node, TartarusLats.MotionVectors.tags(mv))}
          if s.left == 0, do: {:return, s.seen, s}, else: {:move, :conscientious, %{s | left: s.left - 1}}
        end
      end
      """)

    assert {:ok, seen} = TartarusLats.query(dep.hosts[:d], mod, 3)
    assert seen[:d] == [tag]
  end

  # Three zones a - b - c in a line; Y enters at a, stays 25 s, then stays at b.
  defp line_world do
    positions = %{a: {0, 0, 0}, b: {9, 0, 0}, c: {18, 0, 0}}

    building =
      Building.custom(positions: positions, adjacency: %{a: [:b], b: [:c]}, entrances: [:a])

    script = %{name: :y, enter_at: 0, entrance: :a, route: [{:a, 25}, {:b, 10_000}], exit: :b}
    World.new(building: building, walkers: 0, scripts: [script])
  end

  describe "a neighbour that never acknowledges" do
    test "the tag reads as gone from the last node, after the timeout in world seconds" do
      world = line_world()
      dep = Deployment.start(seed: 2, world: world, prefix: "noack")

      try do
        # b's database agent is gone: b hears X but nobody there answers a's notice.
        :ok = Tartarus.kill({"lats-db", dep.hosts[:b]})
        # Y leaves a at 25 s and is at b by about 33 s; a lets it go once its RSSI has been
        # under the exit threshold for 5 s (TartarusLats.Zone), by about 40 s.
        dep = Deployment.run(dep, 45)
        tag = World.tag(dep.world, :y)
        mv = Tartarus.store_get(dep.hosts[:a], {:lats, :mv})
        assert {:a, :pending} = MotionVectors.mvf(mv, tag)

        dep = Deployment.run(dep, 20)
        mv = Tartarus.store_get(dep.hosts[:a], {:lats, :mv})
        assert MotionVectors.mvf(mv, tag) == {:a, :infinity}

        assert {:ok, %{answer: :left_building}} =
                 TartarusLats.query(dep.hosts[:a], :where_is, tag, report: false)
      after
        Deployment.stop(dep)
      end
    end
  end

  describe "how fresh and complete an answer is" do
    # As above (b never acknowledges), with a long handshake timeout: a's vector stays
    # pending, so Where is X answers "in transit from a", current at first, stale later.
    test "in transit: current, then stale past #{TartarusLats.Query.Walk.stale_after()} s; present: current" do
      world = line_world()
      dep = Deployment.start(seed: 2, world: world, prefix: "fresh", timeout: 200)

      try do
        dep = Deployment.run(dep, 20)
        tag = World.tag(dep.world, :y)

        assert {:ok, %{answer: {:in_zone, :a}, freshness: :current, complete: true} = r} =
                 TartarusLats.query(dep.hosts[:c], :where_is, tag, report: false)

        assert r.evidence_at == r.asked_at and r.unreachable == []

        :ok = Tartarus.kill({"lats-db", dep.hosts[:b]})
        dep = Deployment.run(dep, 25)

        assert {:ok, %{answer: {:in_transit, :a}, freshness: :current} = r} =
                 TartarusLats.query(dep.hosts[:a], :where_is, tag, report: false)

        left = r.evidence_at
        assert left < r.asked_at and r.asked_at - left <= 30

        dep = Deployment.run(dep, 40)

        assert {:ok, %{answer: {:in_transit, :a}, freshness: :stale, evidence_at: ^left} = r} =
                 TartarusLats.query(dep.hosts[:a], :where_is, tag, report: false)

        assert r.asked_at - left > 30
      after
        Deployment.stop(dep)
      end
    end
  end

  describe "persistence" do
    @tag :tmp_dir
    test "a node's log and vectors survive a host restart", %{tmp_dir: dir} do
      world = appendix_world()
      dep = Deployment.start(seed: 1, world: world, prefix: "persist", data_dir: dir)

      try do
        dep = Deployment.run(dep, 60)
        host = dep.hosts[:d]
        log = Tartarus.store_get(host, {:lats, :log})
        mv = Tartarus.store_get(host, {:lats, :mv})
        assert length(log) >= 2

        dep = Deployment.restart_node(dep, :d)
        assert Tartarus.store_get(host, {:lats, :log}) == log
        assert Tartarus.store_get(host, {:lats, :mv}).tags == mv.tags
        # what the node knows of its zone comes back with it: d has the door, e has none
        assert Tartarus.store_get(host, {:lats, :entrance}) == true
        dep = Deployment.restart_node(dep, :e)
        assert Tartarus.store_get(dep.hosts[:e], {:lats, :entrance}) == false

        # and the node goes on working: the trace still reaches through d
        dep = Deployment.run(dep, 90)
        tag = World.tag(dep.world, :x)

        assert {:ok, %{answer: {:ok, %{path: path}}}} =
                 TartarusLats.query(dep.hosts[:h], :trace, tag)

        assert nodes(path) == [:d, :e, :f, :i, :h]
      after
        Deployment.stop(dep)
      end
    end
  end

  test "the beacon plugin attaches, describes itself, plays its script and takes writes" do
    {:ok, host} = Tartarus.start_host("beacon-test")

    try do
      tag = {"000000000000000000000000000000aa", 1, 1}

      :ok =
        Tartarus.attach_plugin(
          host,
          :beacon,
          {TartarusLats.BeaconPlugin, node: :n, script: %{1 => %{tag => -60}}}
        )

      [{:beacon, desc}] = Tartarus.plugins(host)
      assert desc.kind == :ble_receiver

      assert {:ok, %{tag => -60}} == Tartarus.read_plugin(host, :beacon, {:scan, 1})
      :ok = Tartarus.write_plugin(host, :beacon, {:readings, 2, %{tag => -70}})
      assert {:ok, %{tag => -70}} == Tartarus.read_plugin(host, :beacon, {:scan, 2})
      assert {:ok, %{}} == Tartarus.read_plugin(host, :beacon, {:scan, 3})

      assert {:error, _} = Tartarus.attach_plugin(host, :bad, {TartarusLats.BeaconPlugin, []})

      assert {:error, _} =
               Tartarus.attach_plugin(
                 host,
                 :bad,
                 {TartarusLats.BeaconPlugin, node: :n, script: 1}
               )
    after
      Tartarus.stop_host(host)
    end
  end
end
