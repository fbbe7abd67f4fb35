defmodule Tartarus.DurablePeerTest do
  # Durable acknowledged messages (host option `durable: true` with `data_dir:`): every post
  # that returned :ok is in the agent's state after its node is SIGKILLed and restarted.
  # Without the option the agent comes back as it was at its last arrival.
  use ExUnit.Case, async: false

  @moduletag :peer
  @moduletag :durable
  alias TartarusTools.Peer
  alias Tartarus.Examples.Echo

  setup do
    dir = Path.join(System.tmp_dir!(), "tartarus_durable_#{System.unique_integer([:positive])}")
    name = :"dur_#{System.unique_integer([:positive])}"
    {:ok, _pid, node} = Peer.start(name, link: false)

    on_exit(fn ->
      if node in Node.list(), do: Peer.kill(node)
      File.rm_rf!(dir)
    end)

    %{node: node, name: name, dir: dir}
  end

  defp host!(node, opts) do
    {:ok, host} = :erpc.call(node, Tartarus, :start_host, [:hd, opts])
    host
  end

  # Five posts acknowledged, the node SIGKILLed and restarted on the same data directory:
  # the state the agent answers with afterwards.
  defp after_crash(%{node: node, name: name, dir: dir}, opts) do
    opts = [data_dir: dir] ++ opts
    h = host!(node, opts)
    {:ok, id} = :erpc.call(node, Tartarus, :create_mobile_agent, [:hd, Echo, :created])
    for i <- 1..5, do: assert(:ok = Tartarus.post({id, h}, {:posted, i}))

    Peer.kill(node)
    {:ok, _pid, ^node} = Peer.start(name, link: false)
    ^h = host!(node, opts)
    Tartarus.request({id, h}, :state)
  end

  test "durable: every acknowledged post survives SIGKILL and restart", ctx do
    assert {:ok, {:posted, 5}} = after_crash(ctx, durable: true)
  end

  test "not durable: the restarted agent has lost the acknowledged posts", ctx do
    assert {:ok, :created} = after_crash(ctx, durable: false)
  end
end
