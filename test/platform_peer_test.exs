defmodule Tartarus.PlatformPeerTest do
  # Agents crossing three real BEAM nodes with a module that only the first node had.
  use ExUnit.Case, async: false

  @moduletag :peer

  @source """
  defmodule TopWanderer do
    use Tartarus.Agent

    def init(owner), do: {:stay, %{owner: owner, log: [], failed: []}}

    def handle_arrival(ctx, s) do
      if ctx.clone_of, do: send(s.owner, {:clone_arrived, Tartarus.Agent.id(), ctx.clone_of, node()})
      {:stay, %{s | log: [ctx.host | s.log]}}
    end

    def handle_message({:go, dest}, _from, s), do: {:move, dest, s}
    def handle_message({:clone, dest}, _from, s), do: {:clone, dest, s}

    def handle_message({:shed, key}, from, s) do
      Tartarus.Agent.reply(from, Tartarus.Agent.shed_payload(key))
      {:stay, s}
    end

    def handle_message(:info, from, s) do
      Tartarus.Agent.reply(from, %{host: Tartarus.Agent.host(), node: node(), log: s.log,
        failed: s.failed, payload: Tartarus.Agent.payload(), hops: Tartarus.Agent.hops()})
      {:stay, s}
    end

    def handle_message({:count, n}, _from, s), do: {:stay, Map.update(s, :count, n, &(&1 + n))}

    def handle_move_failed(dest, reason, _ctx, s) do
      send(s.owner, {:move_failed, dest, reason})
      {:stay, %{s | failed: [{dest, reason} | s.failed]}}
    end
  end
  """

  setup do
    {:ok, peers} = TartarusTools.Peer.start_many("plat", 3)
    [a, b, c] = nodes = Enum.map(peers, &elem(&1, 1))
    hosts = for {n, name} <- Enum.zip(nodes, [:ha, :hb, :hc]), do: {name, n}
    for {name, n} <- hosts, do: {:ok, _} = :erpc.call(n, Tartarus, :start_host, [name])
    [ha, hb, hc] = hosts
    :ok = Tartarus.connect(ha, hb)
    :ok = Tartarus.connect(hb, hc)
    {:ok, [mod]} = :erpc.call(a, Tartarus, :compile_string, [@source])

    on_exit(fn ->
      Enum.each(peers, fn {pid, _} -> TartarusTools.Peer.stop(pid) end)
      for n <- nodes, do: refute(n in Node.list())
    end)

    %{a: a, b: b, c: c, ha: ha, hb: hb, hc: hc, mod: mod, peers: peers}
  end

  test "an agent whose module only the first node had crosses three nodes", ctx do
    %{a: a, b: b, c: c, ha: ha, hb: hb, hc: hc, mod: mod} = ctx
    refute :erpc.call(b, :code, :is_loaded, [mod])
    refute :erpc.call(c, :code, :is_loaded, [mod])

    {:ok, id} =
      :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, mod, self(), [payload: %{note: "hi"}]])

    assert :ok = Tartarus.move({id, ha}, hb)
    assert :ok = Tartarus.move({id, ha}, hc)
    # The code went A -> B -> C, shipped once per link, and loaded from the shipment.
    assert {:file, ~c"tartarus:shipped"} = :erpc.call(b, :code, :is_loaded, [mod])
    assert {:file, ~c"tartarus:shipped"} = :erpc.call(c, :code, :is_loaded, [mod])
    assert :erpc.call(a, Tartarus.Events, :totals, []).code_bytes > 0
    assert :erpc.call(b, Tartarus.Events, :totals, []).code_bytes > 0

    # A message to the agent through its first host follows the forwarding pointers.
    assert {:ok, info} = Tartarus.request({id, ha}, :info)
    assert info.host == hc and info.node == c and info.hops == 2
    assert info.log == [hc, hb]
    assert :ok = Tartarus.post({id, ha}, {:count, 5})
    assert {:ok, %{payload: %{note: "hi"}}} = Tartarus.request({id, hb}, :info)

    # Back to B: the code is cached there, nothing is shipped again.
    code_before = :erpc.call(c, Tartarus.Events, :totals, []).code_bytes
    assert :ok = Tartarus.move({id, hc}, hb)
    assert :erpc.call(c, Tartarus.Events, :totals, []).code_bytes == code_before

    # Clone to C: new id and name, the original stays at B.
    assert {:ok, clone_id} = Tartarus.clone({id, hb}, hc)
    assert clone_id != id
    assert_receive {:clone_arrived, ^clone_id, ^id, ^c}, 5_000
    assert {:ok, %{host: ^hb}} = Tartarus.request({id, hb}, :info)
    assert {:ok, %{host: ^hc}} = Tartarus.request({clone_id, hc}, :info)
    [orig] = Enum.filter(Tartarus.agents(hb), &(&1.id == id))
    [copy] = Enum.filter(Tartarus.agents(hc), &(&1.id == clone_id))
    assert orig.name != copy.name

    # Shed payload: the value stays in B's store and leaves the agent's payload.
    assert {:ok, :ok} = Tartarus.request({id, hb}, {:shed, :note})
    assert Tartarus.store_get(hb, :note) == "hi"
    assert {:ok, %{payload: payload}} = Tartarus.request({id, hb}, :info)
    refute Map.has_key?(payload, :note)
    assert {:ok, {:error, :not_found}} = Tartarus.request({id, hb}, {:shed, :note})
  end

  test "a move to a dead node leaves the agent running at its source", ctx do
    %{a: a, c: c, ha: ha, hb: hb, hc: hc, mod: mod, peers: peers} = ctx
    {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, mod, self()])
    assert :ok = Tartarus.move({id, ha}, hb)
    # B learns where C's host is (a round trip), then C's node dies.
    assert :ok = Tartarus.move({id, hb}, hc)
    assert :ok = Tartarus.move({id, hc}, hb)
    {c_peer, ^c} = List.last(peers)
    TartarusTools.Peer.stop(c_peer)

    assert {:error, reason} = Tartarus.move({id, hb}, hc)
    assert match?({:host_down, _}, reason) or match?({:unknown_host, _}, reason)
    assert_receive {:move_failed, ^hc, ^reason}, 5_000

    # Still alive and answering at B, exactly once across the live nodes.
    assert {:ok, %{host: ^hb, failed: [{^hc, ^reason}]}} = Tartarus.request({id, ha}, :info)
    ids = Enum.flat_map([ha, hb], fn h -> Enum.map(Tartarus.agents(h), & &1.id) end)
    assert Enum.count(ids, &(&1 == id)) == 1

    # A directed move to a host on a node that never existed fails the same way.
    assert {:error, {:unknown_host, _}} = Tartarus.move({id, hb}, {:nowhere, :ghost@nowhere})
    assert {:ok, %{host: ^hb}} = Tartarus.request({id, hb}, :info)
  end

  test "nodes connect only along the hosts' links", %{a: a, c: c, ha: ha, hc: hc, mod: mod} do
    {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, mod, self()])
    # ha -- hb -- hc: walking there hop by hop never connects A and C.
    assert :ok = Tartarus.move({id, ha}, :conscientious)
    assert :ok = Tartarus.move({id, ha}, :conscientious)
    assert {:ok, %{host: ^hc}} = Tartarus.request({id, ha}, :info)
    refute c in :erpc.call(a, Node, :list, [])
  end

  # A hop is three distribution messages between the two nodes: prepare, prepared, commit.
  # (The prepare once went as a distributed spawn_request, which the destination's node
  # answers with a spawn reply whatever the request's reply option: four a hop.) Counted as
  # packets on A's connection to B while one agent bounces between them; acknowledgements
  # are batched, so a few more packets may cross in all.
  test "a hop between two nodes is three distribution messages", %{a: a, b: b, ha: ha, hb: hb} do
    mod = :erpc.call(a, TartarusTools.Bench, :bouncer, [])
    blob = :binary.copy("x", 1024)
    # The first hops ship the code and connect the nodes.
    :erpc.call(a, TartarusTools.Bench, :run_batch, [mod, ha, hb, [20], blob], 60_000)
    {^b, port} = :erpc.call(a, :erlang, :system_info, [:dist_ctrl]) |> List.keyfind(b, 0)

    packets = fn ->
      {:ok, s} = :erpc.call(a, :inet, :getstat, [port, [:send_cnt, :recv_cnt]])
      s[:send_cnt] + s[:recv_cnt]
    end

    hops = 400
    before = packets.()
    :erpc.call(a, TartarusTools.Bench, :run_batch, [mod, ha, hb, [hops], blob], 60_000)
    n = packets.() - before
    assert n >= 3 * hops and n <= 3 * hops + 20, "#{n} packets for #{hops} hops"

    # The door that admits arrivals drops what it does not expect.
    dropped = fn ->
      Map.get(:erpc.call(b, Tartarus.Events, :dropped, []), :tartarus_arrivals, 0)
    end

    send({:tartarus_arrivals, b}, {:junk, 1})
    send({:tartarus_arrivals, b}, {:"$tartarus_arrive", {:nowhere, b}, :not_a_prepare})
    assert {:error, :unexpected_call} = GenServer.call({:tartarus_arrivals, b}, :hello)
    Process.sleep(200)
    assert dropped.() == 2
    assert is_pid(:erpc.call(b, Process, :whereis, [:tartarus_arrivals]))
  end
end
