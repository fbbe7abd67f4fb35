defmodule TartarusEmu.FreshVMTest do
  use ExUnit.Case, async: true

  alias TartarusEmu.FreshVM

  doctest FreshVM

  test "the call runs in another VM, with this VM's configuration, and its result comes back" do
    Application.put_env(:tartarus_emu, :fresh_vm_probe, {:set, self()})

    try do
      assert FreshVM.run({System, :pid, []}) != System.pid()
      # The pid was copied as data: it names this VM's test process.
      assert FreshVM.run({Application, :get_env, [:tartarus_emu, :fresh_vm_probe]}) ==
               {:set, self()}

      started = FreshVM.run({Application, :started_applications, []})
      assert List.keymember?(started, :tartarus, 0)
      refute List.keymember?(started, :tartarus_warehouse, 0)
    after
      Application.delete_env(:tartarus_emu, :fresh_vm_probe)
    end
  end

  test "an exception in the peer is raised here" do
    assert_raise ArgumentError, "no such thing", fn ->
      FreshVM.run({:erlang, :error, [ArgumentError.exception("no such thing")]})
    end

    assert catch_exit(FreshVM.run({:erlang, :exit, [:gone]})) == :gone
  end

  test "a function the peer could not load is refused here, with what it needs" do
    assert_raise ArgumentError, ~r/needs a function a fresh VM can load/, fn ->
      FreshVM.run(fn -> :defined_in_a_test_file end)
    end
  end

  test "portable?/1: functions of modules on disk travel; a closure of a module compiled in memory does not" do
    assert FreshVM.portable?(&System.pid/0)
    assert FreshVM.portable?({:ok, [1, %{a: &Enum.sum/1}]})

    [{mod, _}] =
      Code.compile_string("defmodule FreshVMTest.InMemory do def f, do: fn -> 1 end end")

    refute FreshVM.portable?(mod.f())
    refute FreshVM.portable?([:x, mod.f()])
  end
end
