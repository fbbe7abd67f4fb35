defmodule Tartarus.CastAndPluginIOTest do
  use Tartarus.HostCase, async: false

  test "cast/3 returns at once and delivers like post/3, following a moving agent" do
    [a, b] = [host!(), host!()]
    :ok = Tartarus.connect(a, b)
    id = agent!(a)
    for _ <- 1..20, do: assert(:ok = Tartarus.cast({id, a}, :inc))
    :ok = Tartarus.move({id, a}, b)
    for _ <- 1..20, do: assert(:ok = Tartarus.cast({id, a}, :inc))
    assert eventually(fn -> probe_state({id, b}).count == 40 end)
  end

  test "cast/3 tells reply_to when the agent does not exist" do
    a = host!()
    :ok = Tartarus.cast({"0000000000000000", a}, :inc, self())
    assert_receive {:tartarus_cast_failed, {"0000000000000000", ^a}, :not_found}, 2_000
  end

  test "read_plugin/3 and write_plugin/3 reach a host's device from outside agents" do
    a = host!()
    :ok = Tartarus.attach_plugin(a, :temp, {Tartarus.Plugin.SimSensor, signal: [1.0, 2.0]})
    assert {:ok, 1.0} = Tartarus.read_plugin(a, :temp)
    assert {:ok, 2.0} = Tartarus.read_plugin(a, :temp, :value)
    assert :ok = Tartarus.write_plugin(a, :temp, {:script, [7.0]})
    assert {:ok, 7.0} = Tartarus.read_plugin(a, :temp, :peek)
    assert {:error, {:bad_argument, :nope}} = Tartarus.write_plugin(a, :temp, :nope)
    assert {:error, {:no_such_plugin, :humidity}} = Tartarus.read_plugin(a, :humidity)
    assert {:error, {:unknown_host, _}} = Tartarus.read_plugin({:nowhere, :ghost@nowhere}, :temp)
  end
end
