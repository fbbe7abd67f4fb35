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
end
