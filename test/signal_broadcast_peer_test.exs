defmodule Tartarus.SignalBroadcastPeerTest do
  # Signal fields and neighbour broadcasts between hosts on three real BEAM nodes:
  # ha (node a) - hb (node b) - hc (node c).
  use ExUnit.Case, async: false

  import Tartarus.TestSupport

  @moduletag :peer
  @moduletag :overlay

  @climber """
  defmodule TopClimber do
    use Tartarus.Agent
    alias Tartarus.Agent, as: A

    def init(name), do: step(name)
    def handle_arrival(_ctx, name), do: step(name)

    defp step(name) do
      here = A.signal(name)
      best = name |> A.gradient() |> Map.values() |> Enum.max(fn -> 0.0 end)

      if here > 0 and here >= best,
        do: {:return, {A.host(), A.hops(), node()}, name},
        else: {:move, {:gradient, name}, name}
    end
  end
  """

  setup do
    {:ok, peers} = TartarusTools.Peer.start_many("ovl", 3)
    nodes = Enum.map(peers, &elem(&1, 1))
    hosts = for {n, name} <- Enum.zip(nodes, [:ha, :hb, :hc]), do: {name, n}
    for {name, n} <- hosts, do: {:ok, _} = :erpc.call(n, Tartarus, :start_host, [name])
    [ha, hb, hc] = hosts
    :ok = Tartarus.connect(ha, hb)
    :ok = Tartarus.connect(hb, hc)

    on_exit(fn -> Enum.each(peers, fn {pid, _} -> TartarusTools.Peer.stop(pid) end) end)
    %{nodes: nodes, ha: ha, hb: hb, hc: hc}
  end

  test "a signal spreads hop by hop across nodes and an agent climbs it", ctx do
    %{nodes: [a, b, c], ha: ha, hb: hb, hc: hc} = ctx
    :ok = Tartarus.emit_signal(hc, :danger, 100, span: 2, decay: {:exponential, 0.5})
    assert eventually(fn -> Tartarus.signal(ha, :danger) == 25.0 end)
    assert Tartarus.signal(hb, :danger) == 50.0
    assert Tartarus.signal(hc, :danger) == 100.0
    # Each relay was counted by the host that sent it, on its own node.
    assert :erpc.call(c, Tartarus, :status, [hc]).counts.signal_messages == 1
    assert :erpc.call(b, Tartarus, :status, [hb]).counts.signal_messages == 1
    assert :erpc.call(a, Tartarus, :status, [ha]).counts.signal_messages == 0

    {:ok, [mod]} = :erpc.call(a, Tartarus, :compile_string, [@climber])

    {:ok, id} =
      :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, mod, :danger, [owner: self()]])

    assert_receive {:tartarus_result, ^id, {^hc, 2, ^c}}, 10_000
  end

  test "a broadcast reaches the neighbours on other nodes and is counted", ctx do
    %{nodes: [_a, b, c], ha: ha, hb: hb, hc: hc} = ctx
    :ok = Tartarus.Broadcast.subscribe(ha)
    :ok = Tartarus.Broadcast.subscribe(hc)
    assert Tartarus.broadcast(hb, {:repertoire, [1, 2, 3]}) == {:ok, 2}
    assert_receive {:tartarus_broadcast, ^hb, {:repertoire, [1, 2, 3]}}, 5_000
    assert_receive {:tartarus_broadcast, ^hb, {:repertoire, [1, 2, 3]}}, 5_000
    counts = :erpc.call(b, Tartarus, :status, [hb]).counts
    assert {counts.broadcasts, counts.broadcast_messages} == {1, 2}
    assert counts.broadcast_bytes > 2 * :erlang.external_size({:repertoire, [1, 2, 3]})

    assert eventually(fn ->
             :erpc.call(c, Tartarus, :status, [hc]).counts.broadcasts_received == 1
           end)
  end
end
