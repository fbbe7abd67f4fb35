defmodule Tartarus.RobustServicesTest do
  # Node-level services survive junk, a service's crash leaves the hosts alone, and a host
  # whose server crashes comes back (with its persisted agents).
  use Tartarus.HostCase, async: false

  alias Tartarus.Examples.Echo

  @services [
    Tartarus.AgentTable,
    Tartarus.CodeCache,
    Tartarus.Host.Directory,
    :tartarus_overlay,
    :tartarus_arrivals
  ]

  # The registered processes of the tartarus application (in an umbrella test run, other
  # apps' processes are registered too).
  defp tartarus_registered do
    Enum.filter(Process.registered(), fn name ->
      :application.get_application(Process.whereis(name)) == {:ok, :tartarus}
    end)
  end

  defp echo!(host) do
    {:ok, id} = Tartarus.create_mobile_agent(host, Echo, :init)
    id
  end

  defp answers?(id, host), do: Tartarus.request({id, host}, :where) == {:ok, addr(host)}

  test "the tartarus processes with a registered name are exactly our own services" do
    assert Enum.sort(tartarus_registered()) == Enum.sort(@services)
  end

  test "junk messages, casts and calls to every service are dropped and counted; hosts live on" do
    [a, b] = hosts!(2)
    ids = for h <- [a, b], do: {echo!(h), h}
    pids = Map.new(@services, &{&1, Process.whereis(&1)})
    before = Tartarus.Events.dropped()
    total_before = Tartarus.Events.totals().dropped

    junk = [:hello, {:DOWN, make_ref(), :process, self(), :x}, {:load, :x}, {:load, [1 | 2]}]
    junk = junk ++ [{:watch, :h, :not_a_pid}, {:EXIT, self(), :kill}, "bin", {}]

    for service <- @services, msg <- junk do
      send(service, msg)
      GenServer.cast(service, msg)
      assert {:error, _} = GenServer.call(service, msg, 1_000)
    end

    for service <- @services do
      assert Process.whereis(service) == pids[service]
      # Calls get an answer (2 of the 8 for the cache are {:load, _} it answers itself).
      assert Map.get(Tartarus.Events.dropped(), service, 0) - Map.get(before, service, 0) >= 20
    end

    assert Tartarus.Events.totals().dropped - total_before >= 3 * 20
    assert Enum.sort(Tartarus.hosts()) == Enum.sort(Enum.map([a, b], &addr/1))
    for {id, h} <- ids, do: assert(answers?(id, h))
  end

  test "a crashed service restarts alone; the hosts and the agent table live on" do
    [a] = hosts!(1)
    id = echo!(a)
    host_pid = Tartarus.Host.Directory.whereis(addr(a))

    for service <- @services do
      old = Process.whereis(service)
      ref = Process.monitor(old)
      Process.exit(old, :kill)
      assert_receive {:DOWN, ^ref, _, _, _}
      assert eventually(fn -> Process.whereis(service) not in [nil, old] end)
    end

    assert Tartarus.Host.Directory.whereis(addr(a)) == host_pid
    assert {:ok, _, _} = Tartarus.AgentTable.lookup(id)
    assert answers?(id, a)
  end

  test "a host whose server is killed is restarted; other hosts are untouched" do
    [a, b] = hosts!(2)
    id_b = echo!(b)
    {:ok, pid_a} = Tartarus.Host.Directory.whereis(addr(a))
    {:ok, pid_b} = Tartarus.Host.Directory.whereis(addr(b))

    Process.exit(pid_a, :kill)

    assert eventually(fn ->
             match?({:ok, pid} when pid != pid_a, Tartarus.Host.Directory.whereis(addr(a)))
           end)

    assert {:ok, ^pid_b} = Tartarus.Host.Directory.whereis(addr(b))
    assert answers?(id_b, b)
    # The restarted host works.
    id = echo!(a)
    assert answers?(id, a)
  end

  test "a restarted host with persistence restores its agents and its neighbours" do
    dir = Path.join(System.tmp_dir!(), "tartarus_robust_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    b = host!()
    name = unique_name()
    {:ok, h} = Tartarus.start_host(name, data_dir: dir, neighbours: [b])
    on_exit(fn -> Tartarus.stop_host(name) end)
    ids = for _ <- 1..3, do: echo!(name)
    {:ok, pid} = Tartarus.Host.Directory.whereis(h)

    Process.exit(pid, :kill)

    assert eventually(fn -> Enum.all?(ids, &answers?(&1, name)) end)
    assert {:ok, new_pid} = Tartarus.Host.Directory.whereis(h)
    assert new_pid != pid
    assert Tartarus.neighbours(name) == [addr(b)]
  end

  test "dropping logs at most one line per second per service" do
    start = System.monotonic_time(:millisecond)

    log =
      ExUnit.CaptureLog.capture_log(fn ->
        for i <- 1..200, do: send(Tartarus.CodeCache, {:junk, i})
        # A call after the sends: every send was handled before it returns.
        assert {:error, :unexpected_call} = GenServer.call(Tartarus.CodeCache, :junk)
      end)

    elapsed_s = div(System.monotonic_time(:millisecond) - start, 1_000)
    lines = log |> String.split("\n") |> Enum.count(&(&1 =~ "Tartarus.CodeCache dropped"))
    assert lines <= elapsed_s + 2
    assert Map.fetch!(Tartarus.Events.dropped(), Tartarus.CodeCache) >= 201
  end
end
