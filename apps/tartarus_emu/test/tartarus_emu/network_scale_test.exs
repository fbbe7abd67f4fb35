defmodule TartarusEmu.NetworkScaleTest do
  # 100 peer nodes: tagged :heavy, run with TARTARUS_TESTS=all (Tartarus.TestSupport.Tags). Times are printed, not
  # asserted; figures for the docs come from `mix tartarus.emu --mode peer --hosts 100 --json`.
  use ExUnit.Case, async: false

  alias TartarusEmu.{Network, Topology}

  @moduletag :peer
  @moduletag :heavy
  @moduletag timeout: 900_000

  test "100 peer nodes in a 10x10 grid start, connect to neighbours only, and stop cleanly" do
    topo = Topology.grid(10, 10)
    t0 = System.monotonic_time(:millisecond)
    {:ok, net} = Network.start(topo, mode: :peer)
    t1 = System.monotonic_time(:millisecond)

    try do
      assert length(net.nodes) == 100
      origin = node()

      for n <- topo.nodes do
        node = Network.beam_node(net, n)
        expected = topo |> Topology.neighbours(n) |> Enum.map(&Network.beam_node(net, &1))
        seen = :erpc.call(node, Node, :list, []) -- [origin]
        assert Enum.sort(seen) == Enum.sort(expected)
      end
    after
      assert :ok = Network.stop(net)
    end

    t2 = System.monotonic_time(:millisecond)
    assert Enum.all?(net.nodes, &(&1 not in Node.list()))
    IO.puts("\n100 peers: start #{t1 - t0} ms, stop #{t2 - t1} ms")
  end
end
