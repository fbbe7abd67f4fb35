defmodule TartarusImmune.AgentsTest do
  use ExUnit.Case, async: false

  import Tartarus.TestSupport
  alias TartarusEmu.{Network, Topology}
  alias TartarusImmune.{IPkt, Maths, Node, Params, Sorting}

  @p Params.new!()

  defp line(n, danger \\ true, p \\ @p) do
    state = %{domain: Sorting, p: p, seed: 1, danger: danger}
    hook = fn _n, host -> Tartarus.create_static_agent(host, Node, state, name: "immune") end
    {:ok, net} = Network.start(Topology.line(n), setup: hook)
    on_exit(fn -> Network.stop(net) end)
    {net, Network.host_list(net)}
  end

  defp ipkt(host, fv, run, extra) do
    s =
      Map.merge(
        %{
          sol: Sorting.Insertion,
          fv: fv,
          tau: 10.0,
          zeta: nil,
          n: 0,
          hops: 0,
          tag: 1,
          clones: 0,
          plan: nil,
          p: @p,
          driver: self(),
          run: run,
          sharing: true,
          danger: true
        },
        extra
      )

    {:ok, id} = Tartarus.create_mobile_agent(host, IPkt, s, seed: {1, s.tag})
    id
  end

  defp event(run) do
    receive do
      {:immune, ^run, ev, _tag, _sol} -> ev
    after
      5000 -> :timeout
    end
  end

  test "danger diffusion on a line: Sg_max at the distressed node, Sg_max/2 one hop away, nothing at l_span" do
    {_net, [h1, h2, h3, h4]} = line(4)
    {:ok, :ok} = Tartarus.request({"immune", h1}, {:problems, [{:p2, 0}, {:p2, 1}], 1})
    :ok = Tartarus.Signal.settle()

    assert Enum.map([h1, h2, h3, h4], &Tartarus.signal(&1, {:danger, 1})) == [
             100.0,
             50.0,
             0.0,
             0.0
           ]

    [%{hops: 1, data: fvs}] = Tartarus.Signal.contributions(h2, {:danger, 1})
    assert fvs == Enum.map([0, 1], &Sorting.features(Sorting.instance(:p2, &1, 1)))
  end

  test "no danger signal when danger signals are off" do
    {_net, [h1, h2]} = line(2, false)
    {:ok, :ok} = Tartarus.request({"immune", h1}, {:problems, [{:p2, 0}], 1})
    :ok = Tartarus.Signal.settle()
    assert Tartarus.signal(h2, {:danger, 1}) == 0.0
  end

  test "an iPkt that recognizes the danger climbs it; one that does not wanders; one at the problem stays" do
    {net, [h1, h2, h3]} = line(3)
    fx = Sorting.features(Sorting.instance(:p2, 0, 1))
    {:ok, :ok} = Tartarus.request({"immune", h1}, {:problems, [{:p2, 0}], 1})
    :ok = Tartarus.Signal.settle()
    run = make_ref()
    a = ipkt(h2, fx, run, %{tag: 1})
    # a far feature vector: no recognition
    b = ipkt(h2, [0.0, 0.0, 0.0, 1.0], run, %{tag: 2, sol: Sorting.Quick})
    c = ipkt(h1, fx, run, %{tag: 3})
    assert Network.broadcast(net, {:go, 1}) == 3 + 3
    evs = for _ <- 1..3, do: event(run)
    assert Enum.sort(evs) == [:arrived, :arrived, :stayed]
    assert {:ok, ^h1} = locate(a)
    assert {:ok, ^h1} = locate(c)
    assert {:ok, where} = locate(b)
    assert where in [h1, h3]
    {:ok, q} = Tartarus.request({"immune", h1}, :queue)
    assert Enum.count(q, &(&1.fv == fx)) == 2
  end

  test "signal_life :eq6_5: one hop away a signal (strength 50 of 100) is followed for the first half of the barrage period only" do
    {net, [h1, h2, _h3]} = line(3)
    fx = Sorting.features(Sorting.instance(:p2, 0, 1))
    {:ok, :ok} = Tartarus.request({"immune", h1}, {:problems, [{:p2, 0}], 1})
    :ok = Tartarus.Signal.settle()
    p = Params.new!(signal_life: :eq6_5)

    where = fn age ->
      run = make_ref()
      ids = for tag <- 1..6, do: ipkt(h2, fx, run, %{tag: tag, p: p})
      Network.broadcast(net, {:go, 1, age})
      for _ <- ids, do: assert(event(run) == :arrived)
      hosts = for id <- ids, do: elem(locate(id), 1)
      for id <- ids, do: Tartarus.kill(id)
      hosts
    end

    # age 0.4 < 50/100: all climb to the distressed host
    assert where.(0.4) == List.duplicate(h1, 6)
    # age 0.6: the signal has expired here; they wander conscientiously, not all to h1
    refute where.(0.6) == List.duplicate(h1, 6)
  end

  test "danger_call: a host with a pending problem calls while its queue has room, not once it is full or its problems are solved" do
    p = Params.new!(signal_life: :unserved, q_max: 5)
    fv = [0.1, 0.2, 0.3, 0.4]
    residents = fn n -> List.duplicate(fv, n) end
    # must fire: a pending problem, 4 of 5 places taken
    assert Node.danger_call([fv], residents.(4), p) == [fv]
    # must not fire: the interaction site is full (the call is answered) ...
    assert Node.danger_call([fv], residents.(5), p) == nil
    assert Node.danger_call([fv], residents.(12), p) == nil
    # ... or nothing is pending (a solved problem calls nobody)
    assert Node.danger_call([], [], p) == nil
    # :distressed ignores the queue; a barrage-long signal is never a per-round call
    assert Node.danger_call([fv], residents.(12), %{p | signal_life: :distressed}) == [fv]
    assert Node.danger_call([fv], [], %{p | signal_life: :period}) == nil
    assert Node.per_round?(p) and not Node.per_round?(@p)
  end

  test "danger_call :unmet: a host calls only for the problems no resident recognizes" do
    p = Params.new!(signal_life: :unmet)
    near = [0.1, 0.2, 0.3, 0.4]
    far = [1.0, 1.0, 1.0, 0.0]
    refute Maths.recognizes?(far, near, p)
    # must fire, for the unrecognized problem only
    assert Node.danger_call([near, far], [near], p) == [far]
    assert Node.danger_call([near], [], p) == [near]
    # must not fire: every pending problem has a candidate here, however full the queue
    assert Node.danger_call([near], [near], p) == nil
    assert Node.danger_call([near, far], [near, far], p) == nil
  end

  test "signal_life :unserved: a node diffuses its danger signal per round, only while it has room" do
    p = Params.new!(signal_life: :unserved, q_max: 5)
    {_net, [h1, h2, _h3]} = line(3, true, p)
    fx = Sorting.features(Sorting.instance(:p2, 0, 1))
    {:ok, :ok} = Tartarus.request({"immune", h1}, {:problems, [{:p2, 0}], 1})
    :ok = Tartarus.Signal.settle()
    # no barrage-long signal
    assert Tartarus.signal(h2, {:danger, 1}) == 0.0
    # round 1: the queue is empty, the host calls; its neighbour hears 50 and the problem
    assert {:ok, true} = Tartarus.request({"immune", h1}, {:diffuse, {1, 1}})
    :ok = Tartarus.Signal.settle()
    assert Tartarus.signal(h2, {:danger, {1, 1}}) == 50.0
    assert [%{data: [^fx]}] = Tartarus.Signal.contributions(h2, {:danger, {1, 1}})
    # five iPkts fill the interaction site: round 2 calls nobody
    run = make_ref()
    for tag <- 1..5, do: ipkt(h1, fx, run, %{tag: tag, p: p})
    eventually(fn -> length(queue(h1)) == 5 end)
    assert {:ok, false} = Tartarus.request({"immune", h1}, {:diffuse, {1, 2}})
    :ok = Tartarus.Signal.settle()
    assert Tartarus.signal(h2, {:danger, {1, 2}}) == 0.0
    assert Tartarus.signal(h1, {:danger, {1, 2}}) == 0.0
  end

  test "apoptosis by hops: an iPkt with no hops left dies on its next move and leaves the queue" do
    {net, [h1, _h2]} = line(2)
    run = make_ref()
    _ = ipkt(h1, [0.5, 0.5, 0.5, 0.5], run, %{hops: 1000})
    {:ok, [_]} = Tartarus.request({"immune", h1}, :queue)
    Network.broadcast(net, {:go, 1})
    assert event(run) == :expired
    assert {:ok, []} = Tartarus.request({"immune", h1}, :queue)
  end

  test "a node's interaction: the best solution is selected and clones; losers below tau_min die" do
    {_net, [h1, _]} = line(2)
    run = make_ref()
    fx = Sorting.features(Sorting.instance(:p2, 0, 1))
    _ = ipkt(h1, fx, run, %{tag: 1, sol: Sorting.Quick})
    _ = ipkt(h1, fx, run, %{tag: 2, sol: Sorting.Selection, tau: 6.0})
    {:ok, :ok} = Tartarus.request({"immune", h1}, {:problems, [{:p2, 0}], 1})
    {:ok, r} = Tartarus.request({"immune", h1}, :interact)
    assert r.executed == Sorting.Quick
    assert r.died == [Sorting.Selection]
    # tau 10 + 2 + 0.4 * 6 = 14.4; space 5 - 2 = 3: NC = floor(3 * 14.4 / 20) = 2, capped to
    # floor((14.4 - 5) / 5) = 1
    assert r.born == 1
    assert event(run) == :born
    {:ok, q} = Tartarus.request({"immune", h1}, :queue)
    assert Enum.map(q, & &1.sol) |> Enum.sort() == [Sorting.Quick, Sorting.Quick]
    clone = Enum.find(q, &(&1.tag == {1, 1}))
    assert clone.tau == 5.0 and clone.hops == 0
    # the clone's F_y was hypermutated (from its own random stream)
    assert clone.fv != fx
  end

  test "population control: a full queue blocks cloning" do
    members =
      for i <- 1..5,
          do: {i, %{sol: if(i == 1, do: :a, else: :b), fv: [0.5], tau: 20.0, zeta: nil, n: 0}}

    score = fn
      :a -> 1
      :b -> 2
    end

    p = Map.put(@p, :q_current, 5)
    d = Node.interact(members, [0.5], score, p)
    assert d.selected == 1 and d.nc == 0
    d = Node.interact(Enum.take(members, 2), [0.5], score, Map.put(@p, :q_current, 2))
    assert d.selected == 1 and d.nc == 3
    # no candidate: nothing happens
    assert Node.interact(members, [0.0 - 2.0], score, p) == :no_candidates
  end

  defp locate(id) do
    case Enum.find(Tartarus.hosts(), fn h -> Enum.any?(Tartarus.agents(h), &(&1.id == id)) end) do
      nil -> :error
      h -> {:ok, h}
    end
  end

  defp queue(host) do
    {:ok, q} = Tartarus.request({"immune", host}, :queue)
    q
  end
end
