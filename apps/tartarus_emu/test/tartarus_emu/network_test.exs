defmodule TartarusEmu.NetworkTest do
  use ExUnit.Case, async: true

  import TartarusEmu.EmuCase
  import Tartarus.TestSupport
  alias TartarusEmu.{Dynamics, Network, Topology}

  doctest TartarusEmu.Network

  test "virtual mode: a host per topology node, linked along the edges" do
    topo = Topology.grid(3, 4)
    net = start_network!(topo)

    assert map_size(net.hosts) == 12
    assert net.nodes == [node()]

    for n <- topo.nodes do
      assert neighbour_nodes(net, n) == Topology.neighbours(topo, n)
      assert Network.topo_node(net, Network.host(net, n)) == n
    end

    assert length(Network.live_links(net)) == Topology.edge_count(topo)
  end

  @tag :tmp_dir
  test "node_opts: one node's host journals, and a restarted node gets its options again", %{
    tmp_dir: dir
  } do
    net = start_network!(Topology.line(3), node_opts: %{h2: [data_dir: dir]})
    h2 = Network.host(net, :h2)
    {:ok, id} = Tartarus.create_static_agent(h2, Tartarus.Examples.Echo, :kept)
    :ok = Network.kill_node(net, :h2)
    :ok = Network.restart_node(net, :h2)
    # Restored from h2's journal: the restarted host got its data_dir again.
    assert [%{id: ^id}] = Tartarus.agents(h2)
    assert {:ok, :kept} = Tartarus.request({id, h2}, :state)
  end

  test "the setup hook runs on every node after linking, and again on a restarted node" do
    me = self()

    hook = fn n, host, net ->
      send(me, {:setup, n, length(Tartarus.neighbours(host)), map_size(net.hosts)})
      Tartarus.attach_plugin(host, :sensor, {Tartarus.Plugin.SimSensor, signal: [n]})
    end

    net = start_network!(Topology.line(3), setup: hook)

    for {n, links} <- [h1: 1, h2: 2, h3: 1], do: assert_received({:setup, ^n, ^links, 3})
    assert {:ok, :h2} = Tartarus.read_plugin(Network.host(net, :h2), :sensor)

    :ok = Network.kill_node(net, :h2)
    :ok = Network.restart_node(net, :h2)
    assert_received {:setup, :h2, 2, 3}
    assert {:ok, :h2} = Tartarus.read_plugin(Network.host(net, :h2), :sensor)
  end

  test "a failing setup hook stops start/2 and names the node; a bad hook is refused" do
    hook = fn n, _host -> if n == :h2, do: {:error, :no_sensor}, else: :ok end

    assert {:error, {:setup_failed, :h2, {:error, :no_sensor}}} =
             Network.start(Topology.line(3), setup: hook, prefix: "failsetup")

    # (the host registry forgets a stopped host a moment later)
    assert eventually(fn ->
             not Enum.any?(Tartarus.hosts(), &match?({"failsetup" <> _, _}, &1))
           end)

    assert {:error, msg} = Network.start(Topology.line(2), setup: fn -> :ok end)
    assert msg =~ "for key :setup: expected a function of 2 or 3 arguments"
  end

  test "link latency and loss come from the topology (or the :link default)" do
    topo = Topology.new([:a, :b, :c], [{:a, :b}, {:b, :c}], links: %{{:a, :b} => %{loss: 1.0}})
    net = start_network!(topo, link: [latency_ms: 3])

    defmodule Hop do
      use Tartarus.Agent
      def init(to), do: {:stay, to}
    end

    {:ok, id} = Tartarus.create_mobile_agent(Network.host(net, :b), Hop, nil)

    assert {:error, :link_loss} =
             Tartarus.move({id, Network.host(net, :b)}, Network.host(net, :a))

    assert :ok = Tartarus.move({id, Network.host(net, :b)}, Network.host(net, :c))
  end

  test "break and heal a link" do
    net = start_network!(Topology.line(3))
    assert neighbour_nodes(net, :h2) == [:h1, :h3]

    assert :ok = Network.break_link(net, :h2, :h1)
    assert neighbour_nodes(net, :h1) == []
    assert neighbour_nodes(net, :h2) == [:h3]
    refute Network.live?(net, :h1, :h2)
    assert Network.live_links(net) == [{:h2, :h3}]

    # Strict links: an agent cannot cross a broken link.
    defmodule Still do
      use Tartarus.Agent
      def init(_), do: {:stay, nil}
    end

    {:ok, id} = Tartarus.create_mobile_agent(Network.host(net, :h1), Still, nil)
    h2 = Network.host(net, :h2)
    assert {:error, {:no_link, ^h2}} = Tartarus.move({id, Network.host(net, :h1)}, h2)

    assert :ok = Network.heal_link(net, :h1, :h2)
    assert neighbour_nodes(net, :h1) == [:h2]
    assert :ok = Tartarus.move({id, Network.host(net, :h1)}, h2)

    assert {:error, {:no_such_link, :h1, :h3}} = Network.break_link(net, :h1, :h3)
  end

  test "isolate and rejoin; a broken link stays down when its node rejoins" do
    net = start_network!(Topology.grid(3, 3))
    :ok = Network.break_link(net, :h5, :h6)
    :ok = Network.isolate(net, :h5)

    assert neighbour_nodes(net, :h5) == []
    assert neighbour_nodes(net, :h2) == [:h1, :h3]
    assert Network.isolated(net) == [:h5]

    # Healing a link of an isolated node brings it back only with the node.
    :ok = Network.heal_link(net, :h5, :h6)
    assert neighbour_nodes(net, :h5) == []
    :ok = Network.break_link(net, :h5, :h6)

    :ok = Network.rejoin(net, :h5)
    assert neighbour_nodes(net, :h5) == [:h2, :h4, :h8]
    assert Network.isolated(net) == []
  end

  test "p-dynamics: the network's overlay follows the Dynamics state, down half the time" do
    topo = Topology.ring(20)
    net = start_network!(topo)
    state = Dynamics.new(topo.nodes)

    {down_fraction, _, _} =
      Enum.reduce(1..200, {0, state, Dynamics.rng(5)}, fn _, {acc, st, rng} ->
        {events, st, rng} = Dynamics.step(st, 0.2, rng)
        Network.apply_dynamics(net, events)
        {acc + length(Dynamics.down(st)) / 20, st, rng}
      end)
      |> then(fn {acc, st, rng} -> {acc / 200, st, rng} end)

    # Two-state chain with p_break = p_heal: down half of the time in the long run.
    assert_in_delta down_fraction, 0.5, 0.1

    # The platform's overlay is exactly the live links.
    live = Network.live_links(net)

    overlay = for n <- topo.nodes, m <- neighbour_nodes(net, n), n < m, do: {n, m}

    assert Enum.sort(overlay) == live

    for {a, b} <- live do
      assert Network.up?(net, a) and Network.up?(net, b)
    end
  end

  test "kill and restart a node in virtual mode: it restarts empty and relinked" do
    net = start_network!(Topology.line(3))

    defmodule Idle do
      use Tartarus.Agent
      def init(_), do: {:stay, nil}
    end

    {:ok, _} = Tartarus.create_mobile_agent(Network.host(net, :h2), Idle, nil)
    assert :ok = Network.kill_node(net, :h2)
    assert {:error, _} = Tartarus.status(Network.host(net, :h2))
    refute Network.up?(net, :h2)
    assert Network.broadcast(net, :hello) == 0

    assert :ok = Network.restart_node(net, :h2)
    assert Tartarus.agents(Network.host(net, :h2)) == []
    assert neighbour_nodes(net, :h2) == [:h1, :h3]
  end

  test "broadcast reaches each resident agent once" do
    net = start_network!(Topology.ring(5))

    defmodule Counter do
      use Tartarus.Agent
      def init(owner), do: {:stay, owner}

      def handle_info(:ping, owner) do
        send(owner, {:pong, self()})
        {:stay, owner}
      end
    end

    for n <- [:h1, :h1, :h3],
        do: {:ok, _} = Tartarus.create_mobile_agent(Network.host(net, n), Counter, self())

    assert Network.broadcast(net, :ping) == 3
    for _ <- 1..3, do: assert_receive({:pong, _})
    refute_receive {:pong, _}, 50
  end

  test "stop removes every host; a dead caller takes its network with it" do
    net = start_network!(Topology.line(4))
    hosts = Network.host_list(net)
    assert :ok = Network.stop(net)
    # (The host registry forgets stopped hosts asynchronously.)
    eventually(fn -> Enum.all?(hosts, &(&1 not in Tartarus.hosts())) end)

    test = self()

    pid =
      spawn(fn ->
        {:ok, net} = Network.start(Topology.line(3))
        send(test, {:hosts, Network.host_list(net), net.keeper})
        Process.sleep(:infinity)
      end)

    assert_receive {:hosts, hosts, keeper}
    ref = Process.monitor(keeper)
    Process.exit(pid, :kill)
    assert_receive {:DOWN, ^ref, _, _, _}, 5_000
    eventually(fn -> Enum.all?(hosts, &(&1 not in Tartarus.hosts())) end)
  end

  test "bad options are reported with the key" do
    assert {:error, msg} = Network.start(Topology.line(2), mode: :cloud)
    assert msg =~ "for key :mode"
    assert {:error, msg} = Network.start(Topology.line(2), prefix: 3)
    assert msg =~ ":prefix"
  end
end
