defmodule TartarusEmu.PeerTest do
  # The emulator in :peer mode: one real BEAM node per host, each connected only to the
  # nodes of its overlay neighbours (the origin, this test's node, is connected to all of
  # them: that is how it controls them, so it is left out of the checks).
  use ExUnit.Case, async: false

  alias TartarusEmu.{Network, Scenario, Topology, Walk}

  @moduletag :peer
  @moduletag timeout: 300_000

  # Compiled here, on the origin only: it reaches the peers by migration (code shipping).
  defmodule Explorer do
    use Tartarus.Agent

    def init(n), do: {:move, :conscientious, n}

    def handle_arrival(_ctx, n) do
      visits = Tartarus.Agent.visits()

      if map_size(visits) == n,
        do: {:return, Map.keys(visits), n},
        else: {:move, :conscientious, n}
    end

    def handle_move_failed(_dest, _reason, _ctx, n), do: {:move, :conscientious, n}
  end

  defp peer_links(net, topo_node) do
    :erpc.call(Network.beam_node(net, topo_node), Node, :list, []) -- [node()]
  end

  defp neighbour_nodes(net, topo, n),
    do: topo |> Topology.neighbours(n) |> Enum.map(&Network.beam_node(net, &1)) |> Enum.sort()

  test "a 3x4 grid of 12 BEAM nodes: neighbour-only connections, agents reach every host" do
    topo = Topology.grid(3, 4)
    {:ok, net} = Network.start(topo, mode: :peer)

    try do
      assert length(Enum.uniq(net.nodes)) == 12
      refute node() in net.nodes

      # Agents explore the whole grid, hopping from node to node.
      owner = self()

      ids =
        for start <- [:h1, :h12, :h6] do
          {:ok, id} =
            Tartarus.create_mobile_agent(Network.host(net, start), Explorer, 12,
              owner: owner,
              seed: start
            )

          id
        end

      all_hosts = Enum.sort(Network.host_list(net))

      for id <- ids do
        assert_receive {:tartarus_result, ^id, visited}, 60_000
        assert Enum.sort(visited) == all_hosts
      end

      # Every peer is connected exactly to its neighbours' nodes.
      for n <- topo.nodes do
        assert Enum.sort(peer_links(net, n)) == neighbour_nodes(net, topo, n),
               "#{n} on #{Network.beam_node(net, n)}"
      end

      # Breaking a link drops the BEAM connection between the two nodes; healing restores it.
      :ok = Network.break_link(net, :h1, :h2)
      refute Network.beam_node(net, :h2) in peer_links(net, :h1)
      assert Tartarus.neighbours(Network.host(net, :h1)) == [Network.host(net, :h5)]
      :ok = Network.heal_link(net, :h1, :h2)
      assert Network.beam_node(net, :h2) in peer_links(net, :h1)

      # Killing a node stops its BEAM node; it restarts empty under the same name, relinked.
      h7 = Network.beam_node(net, :h7)
      :ok = Network.kill_node(net, :h7)
      refute h7 in Node.list()
      :ok = Network.restart_node(net, :h7)
      assert Tartarus.agents(Network.host(net, :h7)) == []
      assert Enum.sort(peer_links(net, :h7)) == neighbour_nodes(net, topo, :h7)
      assert length(Tartarus.neighbours(Network.host(net, :h7))) == 4
    after
      assert :ok = Network.stop(net)
    end

    assert Enum.all?(net.nodes, &(&1 not in Node.list()))
  end

  test "the walk scenario in peer mode with grouped hosts covers the grid" do
    {:ok, %{summary: s}} =
      Scenario.run(Walk,
        mode: :peer,
        group: 2,
        topology: "grid",
        hosts: 12,
        agents: 4,
        steps: 200,
        seed: 5,
        strategy: :conscientious,
        until_covered: true,
        quiet: true,
        out: false
      )

    assert s.coverage == 1.0
    assert s.mode == :peer
    assert s.lost_reports == 0
    assert s.migrations > 0
  end
end
