defmodule Tartarus.MigrationReplayPeerTest do
  # A sealed `prepare` captured at its destination and sent again, from a third node, after
  # the agent moved on (Tartarus.Migration.Protocol, "At most one running copy"): real BEAM
  # nodes, hosts with signed hand-offs. The destination refuses it while it remembers the
  # migration; once it forgot (it restarted), the copy the replay makes is told aborted by
  # the source. Either way the agent runs exactly once.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport

  @moduletag :peer
  alias Tartarus.Examples.Echo
  alias Tartarus.Fault
  alias Tartarus.Security.{Keys, TrustList}
  alias TartarusTools.Peer

  setup do
    tag = System.unique_integer([:positive])
    [a, b, c] = for n <- [:ra, :rb, :rc], do: start_node(:"#{n}_#{tag}")

    on_exit(fn -> Enum.each([a, b, c], &Peer.kill/1) end)

    issuer = Keys.generate()
    keys = Keys.generate()
    trust = TrustList.new([issuer.public, keys.public])
    opts = [migration_timeout: 500, security: [keys: keys, trust: trust]]
    ha = host!(a, :ha, opts)
    hb = host!(b, :hb, opts)
    hc = host!(a, :hc, opts)
    {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, Echo, :s0, [issuer: issuer]])
    %{a: a, b: b, c: c, ha: ha, hb: hb, hc: hc, id: id, opts: opts}
  end

  defp start_node(name) do
    {:ok, _pid, node} = Peer.start(name, link: false)
    node
  end

  defp host!(node, name, opts) do
    {:ok, host} = :erpc.call(node, Tartarus, :start_host, [name, opts])
    host
  end

  defp copies(id, hosts),
    do: hosts |> Enum.flat_map(&Tartarus.agents/1) |> Enum.count(&(&1.id == id))

  defp paused({_, node} = host), do: :erpc.call(node, Tartarus.Host, :call, [host, :paused])
  defp refused({_, node} = host), do: :erpc.call(node, Tartarus, :status, [host]).counts.refused

  # Moves the agent a -> b, capturing the sealed prepare as b's server receives it, then
  # on b -> c: the captured prepare is the old migration's.
  defp capture_then_move_on(%{b: b, ha: ha, hb: hb, hc: hc, id: id}) do
    :ok = :erpc.call(b, Fault, :install, [:prepare_received, {:once, {:pause, self()}}])
    mover = Task.async(fn -> Tartarus.move({id, ha}, hb) end)
    assert_receive {:fault_paused, :prepare_received, server, prepare}, 5_000
    send(server, {:fault_continue, server})
    assert :ok = Task.await(mover, 10_000)
    assert {:ok, ^hb} = Tartarus.request({id, hb}, :where)
    assert :ok = Tartarus.move({id, hb}, hc)
    assert {:ok, ^hc} = Tartarus.request({id, hc}, :where)
    # Sealed: the seal covers the reply-to pids, the source and the kind.
    assert %{hop: {_, _}} = elem(prepare, 6).signature
    prepare
  end

  test "replayed from a third node while the destination remembers it: refused, one copy",
       ctx do
    %{b: b, c: c, ha: ha, hb: hb, hc: hc, id: id} = ctx
    prepare = capture_then_move_on(ctx)
    before = refused(hb)
    {:ok, server} = :erpc.call(b, Tartarus.Host, :whereis, [hb])

    :erpc.call(c, Kernel, :send, [server, prepare])

    eventually(fn -> refused(hb) == before + 1 end, 10_000)
    assert paused(hb) == 0
    assert copies(id, [ha, hb, hc]) == 1
    assert {:ok, :s0} = Tartarus.request({id, hc}, :state)
  end

  test "replayed after the destination forgot it (restarted): its copy is aborted, one copy",
       ctx do
    %{b: b, c: c, ha: ha, hb: hb, hc: hc, id: id, opts: opts} = ctx
    prepare = capture_then_move_on(ctx)
    :ok = :erpc.call(b, Tartarus, :stop_host, [hb])
    ^hb = host!(b, :hb, opts)
    {:ok, server} = :erpc.call(b, Tartarus.Host, :whereis, [hb])

    :ok = :erpc.call(b, Fault, :install, [:admitting, {:once, {:pause, self()}}])
    :erpc.call(c, Kernel, :send, [server, prepare])

    # Admitted (its seal holds and nothing remembers it): a paused copy is made, which asks
    # the source; the source committed another copy of that migration: aborted.
    # Admitted by a process of its own (Tartarus.Host.Arrivals), not the server.
    assert_receive {:fault_paused, :admitting, admitting, _env}, 5_000
    assert node(admitting) == b and admitting != server
    send(admitting, {:fault_continue, admitting})
    eventually(fn -> paused(hb) == 0 end, 10_000)
    assert copies(id, [ha, hb, hc]) == 1
    assert {:ok, :s0} = Tartarus.request({id, hc}, :state)
    assert Tartarus.agents(hb) == []
  end
end
