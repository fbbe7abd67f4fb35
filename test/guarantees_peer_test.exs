defmodule Tartarus.GuaranteesPeerTest do
  # The migration guarantees of DESIGN §6 under faults injected at exact protocol points,
  # with real BEAM nodes killed (SIGKILL), restarted and partitioned. Each test asserts the
  # guarantee itself: the agent exists exactly once across the cluster.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport

  @moduletag :peer
  alias Tartarus.Fault
  alias TartarusTools.Peer
  alias Tartarus.Examples.Echo

  setup do
    dir =
      Path.join(System.tmp_dir!(), "tartarus_guarantees_#{System.unique_integer([:positive])}")

    tag = System.unique_integer([:positive])
    names = [:"gs_#{tag}", :"gd_#{tag}"]
    nodes = for n <- names, do: start_node(n)

    on_exit(fn ->
      for n <- Node.list(),
          String.ends_with?(Atom.to_string(n) |> String.split("@") |> hd(), "_#{tag}"),
          do: Peer.kill(n)

      File.rm_rf!(dir)
    end)

    [a, b] = nodes
    %{a: a, b: b, names: names, dir: dir}
  end

  defp start_node(name) do
    {:ok, _pid, node} = Peer.start(name, link: false)
    node
  end

  defp host!(node, name, opts \\ []) do
    {:ok, host} =
      :erpc.call(node, Tartarus, :start_host, [name, [migration_timeout: 500] ++ opts])

    host
  end

  defp copies(id, hosts) do
    hosts
    |> Enum.flat_map(fn {_, node} = h ->
      if node in Node.list(), do: Tartarus.agents(h), else: []
    end)
    |> Enum.count(&(&1.id == id))
  end

  test "destination killed before it answers prepared: the agent runs on at the source", %{
    a: a,
    b: b
  } do
    ha = host!(a, :ha)
    hb = host!(b, :hb)
    {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, Echo, :s0])
    :ok = :erpc.call(b, Fault, :install, [:admitting, {:once, {:pause, self()}}])

    mover = Task.async(fn -> Tartarus.move({id, ha}, hb) end)
    assert_receive {:fault_paused, :admitting, _pid, _env}, 5_000
    Peer.kill(b)

    assert {:error, {:host_down, _}} = Task.await(mover, 10_000)
    assert {:ok, ^ha} = Tartarus.request({id, ha}, :where)
    assert {:ok, :s0} = Tartarus.request({id, ha}, :state)
    assert copies(id, [ha]) == 1
  end

  test "destination killed after prepared: with persistence it restarts and finishes the move",
       %{a: a, b: b, names: [_, nb], dir: dir} do
    ha = host!(a, :ha)
    hb = host!(b, :hb, data_dir: Path.join(dir, "b"))
    {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, Echo, :s1])
    :ok = :erpc.call(a, Fault, :install, [:prepared, {:once, {:pause, self()}}])

    :ok = Tartarus.post({id, ha}, {:go, hb})
    assert_receive {:fault_paused, :prepared, s_pid, _new_pid}, 5_000
    Peer.kill(b)
    # The source commits to a dead node: the commit is lost, the copy at b is in doubt on disk.
    Fault.continue(s_pid)
    |> then(fn :ok -> :erpc.call(a, Kernel, :send, [s_pid, {:fault_continue, s_pid}]) end)

    b2 = start_node(nb)
    assert b2 == b
    ^hb = host!(b, :hb, data_dir: Path.join(dir, "b"))

    eventually(fn -> Tartarus.whereis({id, ha}) == {:ok, hb} end, 10_000)
    assert {:ok, :s1} = Tartarus.request({id, ha}, :state)
    assert copies(id, [ha, hb]) == 1
  end

  test "source killed after deciding to commit: with persistence the destination learns the commit",
       %{a: a, b: b, names: [na, _], dir: dir} do
    ha = host!(a, :ha, data_dir: Path.join(dir, "a"))
    hb = host!(b, :hb)
    {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, Echo, :s2])
    :ok = :erpc.call(a, Fault, :install, [:committing, {:once, {:pause, self()}}])

    :ok = Tartarus.post({id, ha}, {:go, hb})
    assert_receive {:fault_paused, :committing, _s_pid, _new_pid}, 5_000
    Peer.kill(a)
    # b holds a paused copy and asks a (dead) again and again: it waits, it does not guess.
    Process.sleep(1_500)
    assert copies(id, [hb]) == 0

    ^a = start_node(na)
    ^ha = host!(a, :ha, data_dir: Path.join(dir, "a"))

    eventually(fn -> copies(id, [hb]) == 1 end, 10_000)
    assert copies(id, [ha, hb]) == 1
    assert {:ok, :s2} = Tartarus.request({id, hb}, :state)
  end

  test "partition during the hand-off: the destination waits and finishes after healing",
       %{a: a, b: b} do
    ha = host!(a, :ha)
    hb = host!(b, :hb)
    {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, Echo, :s3])
    :ok = :erpc.call(a, Fault, :install, [:committing, {:once, {:pause, self()}}])

    :ok = Tartarus.post({id, ha}, {:go, hb})
    assert_receive {:fault_paused, :committing, s_pid, _}, 5_000
    :ok = Peer.partition(a, b)
    :erpc.call(a, Kernel, :send, [s_pid, {:fault_continue, s_pid}])

    # The commit could not cross; the source's copy is gone (it committed), b's is paused.
    Process.sleep(1_500)
    assert copies(id, [ha, hb]) == 0
    refute b in :erpc.call(a, Node, :list, [])

    :ok = Peer.heal(a, b)
    eventually(fn -> copies(id, [hb]) == 1 end, 10_000)
    assert copies(id, [ha, hb]) == 1
    assert {:ok, :s3} = Tartarus.request({id, ha}, :state)
  end

  test "a commit delivered twice changes nothing", %{a: a, b: b} do
    ha = host!(a, :ha)
    hb = host!(b, :hb)
    {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, Echo, :s4])
    :ok = :erpc.call(a, Fault, :install, [:committing, {:once, {:pause, self()}}])

    :ok = Tartarus.post({id, ha}, {:go, hb})
    assert_receive {:fault_paused, :committing, s_pid, new_pid}, 5_000
    :erpc.call(a, Kernel, :send, [s_pid, {:fault_continue, s_pid}])
    eventually(fn -> copies(id, [hb]) == 1 end, 10_000)
    {:ok, hops} = Tartarus.request({id, hb}, :hops)

    # The same commit again, from the source's node.
    for _ <- 1..3,
        do:
          :erpc.call(a, Kernel, :send, [
            new_pid,
            Tartarus.Migration.Messages.commit(
              {"x", make_ref()},
              :crypto.strong_rand_bytes(16),
              nil
            )
          ])

    assert {:ok, ^hops} = Tartarus.request({id, hb}, :hops)
    assert copies(id, [ha, hb]) == 1
  end

  test "clock skew between nodes does not matter", %{a: a, b: b} do
    ha = host!(a, :ha)
    hb = host!(b, :hb)
    {:ok, id} = :erpc.call(a, Tartarus, :create_mobile_agent, [:ha, Echo, :s5])

    for skew <- [3_600_000_000, -3_600_000_000] do
      :ok =
        :erpc.call(a, Fault, :install, [
          :outgoing,
          {:once, {:transform, {Fault, :skew_clock, [skew]}}}
        ])

      assert :ok = Tartarus.move({id, ha}, hb)
      assert :ok = Tartarus.move({id, hb}, ha)
      assert copies(id, [ha, hb]) == 1
    end

    assert {:ok, :s5} = Tartarus.request({id, ha}, :state)
    assert Tartarus.hop_stats(hb).count == 2
  end
end
