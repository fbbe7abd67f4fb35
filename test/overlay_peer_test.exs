defmodule Tartarus.OverlayPeerTest do
  # Overlay changes come only from the host's own node or, with security on, from the nodes
  # its trust list names; a remote connect names a host that must exist; the neighbour set
  # is bounded.
  use ExUnit.Case, async: false

  alias Tartarus.Security.{Keys, TrustList}

  @moduletag :peer
  @moduletag :overlay

  @props %{latency_ms: 0, loss: 0}

  setup do
    {:ok, peers} = TartarusTools.Peer.start_many("overlay", 2)
    [a, b] = nodes = Enum.map(peers, &elem(&1, 1))

    on_exit(fn ->
      Enum.each(peers, fn {pid, _} -> TartarusTools.Peer.stop(pid) end)
      for n <- nodes, do: refute(n in Node.list())
    end)

    %{a: a, b: b}
  end

  defp server(host) do
    {name, node} = host
    {:ok, pid} = :erpc.call(node, Tartarus.Host.Directory, :whereis, [{name, node}])
    pid
  end

  # A raw call to a host's server, made by a process on `from_node`.
  defp raw_call(from_node, host, request) do
    :erpc.call(from_node, GenServer, :call, [server(host), request, 5_000])
  end

  test "a node cannot add fake neighbours to another node's host", %{a: a, b: b} do
    {:ok, ha} = :erpc.call(a, Tartarus, :start_host, [:ha])
    {:ok, hb} = :erpc.call(b, Tartarus, :start_host, [:hb])

    fake = {:fake, :nowhere@nohost}
    assert raw_call(b, ha, {:connect, fake, @props}) == {:error, {:untrusted_node, b}}
    assert raw_call(b, ha, {:connect, hb, @props}) == {:error, {:untrusted_node, b}}
    assert raw_call(b, ha, {:disconnect, hb}) == {:error, {:untrusted_node, b}}
    assert Tartarus.neighbours(ha) == []

    # Tartarus.connect/3, from any node (here a third one), asks each end on its own node.
    assert Tartarus.connect(ha, hb) == :ok
    assert Tartarus.neighbours(ha) == [hb]
    assert Tartarus.neighbours(hb) == [ha]
    # ... and a remote disconnect is refused: the link stays.
    assert raw_call(b, ha, {:disconnect, hb}) == {:error, {:untrusted_node, b}}
    assert Tartarus.neighbours(ha) == [hb]
    assert Tartarus.disconnect(ha, hb) == :ok
    assert Tartarus.neighbours(ha) == []
  end

  test "with security on, a trusted node may link, only to hosts that exist", %{a: a, b: b} do
    trust = TrustList.new([Keys.generate().public]) |> TrustList.trust_node(b)
    {:ok, ha} = :erpc.call(a, Tartarus, :start_host, [:ha, [security: [trust: trust]]])
    {:ok, hb} = :erpc.call(b, Tartarus, :start_host, [:hb])

    assert raw_call(b, ha, {:connect, {:fake, b}, @props}) ==
             {:error, {:unknown_host, {:fake, b}}}

    assert raw_call(b, ha, {:connect, hb, @props}) == :ok
    assert Tartarus.neighbours(ha) == [hb]
    # The test node is not trusted.
    assert GenServer.call(server(ha), {:disconnect, hb}) == {:error, {:untrusted_node, node()}}
    assert raw_call(b, ha, {:disconnect, hb}) == :ok
    assert Tartarus.neighbours(ha) == []
  end

  test "the neighbour set is bounded by :max_neighbours", %{a: a} do
    {:ok, h} = :erpc.call(a, Tartarus, :start_host, [:h, [max_neighbours: 2]])
    others = for n <- 1..3, do: elem(:erpc.call(a, Tartarus, :start_host, [:"o#{n}"]), 1)
    [o1, o2, o3] = others
    assert Tartarus.connect(h, o1) == :ok
    assert Tartarus.connect(h, o2) == :ok
    assert Tartarus.connect(h, o3) == {:error, {:too_many_neighbours, 2}}
    # Re-linking an existing neighbour (new properties) is not a new link.
    assert Tartarus.connect(h, o2, latency_ms: 5) == :ok
    assert Enum.sort(Tartarus.neighbours(h)) == Enum.sort([o1, o2])
  end

  test "a host's short name is resolved through the overlay and an agent found by its id alone",
       %{a: a, b: b} do
    {:ok, h1} = :erpc.call(a, Tartarus, :start_host, [:h1])
    {:ok, h2} = :erpc.call(b, Tartarus, :start_host, [:h2])
    :ok = Tartarus.connect(h1, h2)
    echo = Tartarus.Examples.Echo
    {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:h1, echo, :kept])

    # As a user on a's node types it: h2 is a neighbour of h1, on the other node.
    assert :erpc.call(a, Tartarus, :move, [{id, :h1}, :h2]) == :ok
    # By its id alone, from the node it left (its pointer), from its own node, and from a
    # node without hosts (this one: it asks the nodes it is connected to).
    assert :erpc.call(a, Tartarus, :whereis, [id]) == {:ok, h2}
    assert :erpc.call(b, Tartarus, :whereis, [id]) == {:ok, h2}
    assert Tartarus.whereis(id) == {:ok, h2}
    assert {:ok, :kept} = :erpc.call(a, Tartarus, :request, [id, :state])
    assert :erpc.call(a, Tartarus, :whereis, ["0123456789abcdef"]) == {:error, :not_found}

    # A host named like the neighbour, on the agent's own node: the neighbour is meant.
    {:ok, _} = :erpc.call(b, Tartarus, :start_host, [:h1])
    assert :erpc.call(b, Tartarus, :move, [{id, :h2}, :h1]) == :ok
    assert Tartarus.whereis(id) == {:ok, h1}

    # Two neighbours of that name on other nodes: ambiguous, and the agent stays.
    {:ok, [{pc, c}]} = TartarusTools.Peer.start_many("overlay_c", 1)
    on_exit(fn -> TartarusTools.Peer.stop(pc) end)
    {:ok, h2c} = :erpc.call(c, Tartarus, :start_host, [:h2])
    :ok = Tartarus.connect(h1, h2c)

    assert :erpc.call(a, Tartarus, :move, [{id, :h1}, :h2]) ==
             {:error, {:ambiguous_host, :h2, Enum.sort([h2, h2c])}}

    assert Tartarus.whereis(id) == {:ok, h1}
  end

  test "a neighbour's short name is resolved in an agent reference and in agents/1 and status/2",
       %{a: a, b: b} do
    {:ok, h1} = :erpc.call(a, Tartarus, :start_host, [:n1])
    {:ok, h2} = :erpc.call(b, Tartarus, :start_host, [:n2])
    :ok = Tartarus.connect(h1, h2)
    echo = Tartarus.Examples.Echo
    {:ok, id} = :erpc.call(b, Tartarus, :create_mobile_agent, [:n2, echo, :kept])

    # On a's node, as a user types it: n2 is a neighbour of a's host, on another node.
    assert [%{id: ^id}] = :erpc.call(a, Tartarus, :agents, [:n2])
    assert %{resident: 1} = :erpc.call(a, Tartarus, :status, [:n2, [:resident]])
    assert :erpc.call(a, Tartarus, :move, [{id, :n2}, :n1]) == :ok
    assert :erpc.call(a, Tartarus, :whereis, [{id, :n2}]) == {:ok, h1}
    # A name that is neither local nor a neighbour is still unknown.
    assert :erpc.call(a, Tartarus, :agents, [:n9]) == {:error, {:unknown_host, {:n9, a}}}
  end

  @tag :fleet
  test "the fleet is listed from any node: each node's hosts, their agents and neighbours",
       %{a: a, b: b} do
    {:ok, h1} = :erpc.call(a, Tartarus, :start_host, [:f1])
    {:ok, h2} = :erpc.call(b, Tartarus, :start_host, [:f2])
    {:ok, h3} = :erpc.call(b, Tartarus, :start_host, [:f3])
    :ok = Tartarus.connect(h1, h2)
    :ok = Tartarus.connect(h2, h3)
    echo = Tartarus.Examples.Echo
    for _ <- 1..2, do: {:ok, _} = :erpc.call(b, Tartarus, :create_mobile_agent, [:f3, echo, nil])
    {:ok, _} = :erpc.call(a, Tartarus, :create_mobile_agent, [:f1, echo, nil])

    expected = [
      %{node: a, agents: 1, hosts: [%{host: h1, agents: 1, neighbours: [h2]}]},
      %{
        node: b,
        agents: 2,
        hosts: [
          %{host: h2, agents: 0, neighbours: Enum.sort([h1, h3])},
          %{host: h3, agents: 2, neighbours: [h2]}
        ]
      }
    ]

    sorted = fn fleet ->
      for n <- fleet,
          do: %{n | hosts: for(h <- n.hosts, do: %{h | neighbours: Enum.sort(h.neighbours)})}
    end

    # From either node (through the overlay), and from a node without hosts (this one: it
    # asks the nodes it is connected to, and is listed with none).
    assert sorted.(:erpc.call(a, Tartarus, :fleet, [])) == expected
    assert sorted.(:erpc.call(b, Tartarus, :fleet, [])) == expected
    me = %{node: node(), agents: 0, hosts: []}
    assert sorted.(Tartarus.fleet()) == Enum.sort_by([me | expected], & &1.node)

    # A neighbour's node that is gone is listed as not reached.
    {:ok, [{pc, c}]} = TartarusTools.Peer.start_many("overlay_c", 1)
    on_exit(fn -> TartarusTools.Peer.stop(pc) end)
    {:ok, h4} = :erpc.call(c, Tartarus, :start_host, [:f4])
    :ok = Tartarus.connect(h1, h4)
    assert Enum.map(:erpc.call(a, Tartarus, :fleet, []), & &1.node) == Enum.sort([a, b, c])
    TartarusTools.Peer.stop(pc)

    assert %{node: ^c, hosts: [], error: :not_reached} =
             Enum.find(:erpc.call(a, Tartarus, :fleet, []), &(&1.node == c))
  end

  # The walk carries the nodes it asked back up: a search for an unknown id asks each node of
  # a 4x4 grid once (before, siblings did not learn what the other had asked: 131 calls
  # from a corner). Counted with call_count tracing of the walk on every node.
  @tag timeout: 180_000
  test "a search for an unknown id asks each node of a 4x4 grid at most once" do
    {:ok, peers} = TartarusTools.Peer.start_many("grid", 16)
    nodes = Enum.map(peers, &elem(&1, 1))
    on_exit(fn -> Enum.each(peers, fn {pid, _} -> TartarusTools.Peer.stop(pid) end) end)

    hosts =
      for {n, i} <- Enum.with_index(nodes) do
        {:ok, h} = :erpc.call(n, Tartarus, :start_host, [:"g#{i}"])
        h
      end

    grid = List.to_tuple(hosts)

    for i <- 0..15, j <- [i + 1, i + 4], j < 16, j == i + 4 or rem(i, 4) != 3 do
      :ok = Tartarus.connect(elem(grid, i), elem(grid, j))
    end

    # (Loaded first: a pattern matches only the functions of loaded modules.)
    for n <- nodes do
      {:module, _} = :erpc.call(n, :code, :ensure_loaded, [Tartarus.Locator.Walk])
      pattern = {Tartarus.Locator.Walk, :_, :_}
      assert :erpc.call(n, :erlang, :trace_pattern, [pattern, true, [:call_count]]) > 0
    end

    assert :erpc.call(hd(nodes), Tartarus, :whereis, ["0123456789abcdef"]) == {:error, :not_found}

    # Every call that asks a node: walk/4 (and search/3, which asked each node before the
    # walk existed), but the corner's own search/3, the entry that starts the walk.
    counts =
      for n <- nodes do
        funs = if n == hd(nodes), do: [{:walk, 4}], else: [{:search, 3}, {:walk, 4}]

        for fun <- funs, reduce: 0 do
          acc ->
            {name, arity} = fun

            case :erpc.call(n, :erlang, :trace_info, [
                   {Tartarus.Locator.Walk, name, arity},
                   :call_count
                 ]) do
              {:call_count, c} when is_integer(c) -> acc + c
              _ -> acc
            end
        end
      end

    # 16 nodes, each asked at most once (131 calls before the walk).
    assert Enum.sum(counts) <= 16
    assert Enum.all?(counts, &(&1 <= 1))

    # An agent on the far corner is still found.
    {:ok, far} =
      :erpc.call(List.last(nodes), Tartarus, :create_mobile_agent, [
        :g15,
        Tartarus.Examples.Echo,
        :kept
      ])

    assert :erpc.call(hd(nodes), Tartarus, :whereis, [far]) == {:ok, elem(grid, 15)}
  end
end
