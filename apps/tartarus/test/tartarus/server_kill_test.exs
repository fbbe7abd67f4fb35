defmodule Tartarus.ServerKillTest do
  # A host's server killed with an untrappable :kill: its agents live on (their tables, the
  # journal and the callback watchdog are the host's warden's) and the restarted server
  # adopts them: listed, answering, killable, movable, no orphan, no duplicate, none lost.
  # Tartarus.agents/0 lists only agents that exist.
  use Tartarus.HostCase, async: false

  alias Tartarus.Test.Probe

  defmodule Sleeper do
    @moduledoc false
    use Tartarus.Agent
    def init(s), do: {:stay, s}

    def handle_message({:sleep, ms}, from, s) do
      Process.sleep(ms)
      Tartarus.Agent.reply(from, :slept)
      {:stay, s}
    end
  end

  defp dir do
    dir = Path.join(System.tmp_dir!(), "server_kill_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    dir
  end

  # Kills the host's server and waits for the next one.
  defp kill_server!(h) do
    {:ok, old} = Tartarus.Host.whereis(addr(h))
    Process.exit(old, :kill)

    {:ok, _} =
      wait_for(fn ->
        match?({:ok, pid} when pid != old, Tartarus.Host.whereis(addr(h))) and
          Tartarus.Host.call(addr(h), :adopted) |> is_integer()
      end)

    :ok
  end

  defp ids(h), do: h |> Tartarus.agents() |> Enum.map(& &1.id) |> Enum.sort()

  defp all_answer(h, ids) do
    Enum.all?(ids, fn id ->
      match?({:ok, %{count: _}}, Tartarus.request({id, addr(h)}, :state))
    end)
  end

  for persist <- [false, true] do
    @persist persist
    test "server :kill (data_dir: #{persist}): 20 agents listed and answering at once and after a callback budget" do
      opts = [callback_timeout: 500] ++ if(@persist, do: [data_dir: dir()], else: [])
      h = host!(opts)
      created = Enum.sort(for _ <- 1..20, do: agent!(h, %{count: 0}))
      :ok = kill_server!(h)

      assert ids(h) == created
      assert all_answer(h, created)
      assert Tartarus.Host.call(addr(h), :adopted) == 20

      # Their callback budgets were armed against the warden, not the dead server: after
      # more than one budget they still answer (before, each exited
      # {:callback_timeout, :handle_message, _} after its first request).
      Process.sleep(800)
      assert ids(h) == created
      assert all_answer(h, created)

      # Killable and movable through the new server.
      [a, b | _] = created
      h2 = host!()
      :ok = Tartarus.connect(h, h2)
      assert :ok = Tartarus.kill({a, addr(h)})
      assert :ok = Tartarus.move({b, addr(h)}, h2)
      assert ids(h) == created -- [a, b]
      assert ids(h2) == [b]
    end
  end

  test "after a server :kill, a restart of the host restores each persisted agent once" do
    d = dir()
    name = unique_name()
    {:ok, _} = Tartarus.start_host(name, data_dir: d)
    created = Enum.sort(for _ <- 1..20, do: agent!(name, %{count: 0}))
    :ok = kill_server!(name)
    assert ids(name) == created
    :ok = Tartarus.stop_host(name)
    assert Enum.filter(Tartarus.agents(), &(&1.id in created)) == []

    {:ok, _} = Tartarus.start_host(name, data_dir: d)
    on_exit(fn -> Tartarus.stop_host(name) end)
    assert ids(name) == created
    assert all_answer(name, created)
  end

  test "an agent whose callback overruns after a server :kill is still stopped by the watchdog" do
    h = host!(callback_timeout: 200)
    {:ok, id} = Tartarus.create_agent(h, Sleeper, nil)
    :ok = kill_server!(h)
    assert ids(h) == [id]

    # Its budget's timer goes to the warden: the request is answered with the overrun and
    # the agent removed (not restarted), though the server that was there when it started
    # is gone.
    assert {:error, {:callback_timeout, :handle_message, 200}} =
             Tartarus.request({id, addr(h)}, {:sleep, 2_000})

    assert {:ok, _} = wait_for(fn -> ids(h) == [] end)
  end

  test "creation flood with the server killed half-way: every {:ok, id} agent is listed, none is left after stop_host" do
    name = unique_name()
    {:ok, _} = Tartarus.start_host(name)
    test = self()

    creators =
      for _ <- 1..4 do
        spawn_link(fn ->
          results = for _ <- 1..1_500, do: Tartarus.create_agent(name, Probe, %{count: 0})
          send(test, {:created, self(), results})
        end)
      end

    assert {:ok, _} = wait_for(fn -> Tartarus.Ledger.counter(local!(name), :resident) > 1_000 end)
    {:ok, server} = Tartarus.Host.whereis(addr(name))
    Process.exit(server, :kill)

    results =
      Enum.flat_map(creators, fn pid ->
        receive do
          {:created, ^pid, results} -> results
        after
          60_000 -> flunk("creators did not finish")
        end
      end)

    ok = for {:ok, id} <- results, do: id
    assert length(ok) > 1_000
    # Refusals name a cause (the host was restarting), nothing else.
    for r <- results, not match?({:ok, _}, r), do: assert({:error, _} = r)

    assert {:ok, _} = wait_for(fn -> MapSet.subset?(MapSet.new(ok), MapSet.new(ids(name))) end)
    # No agent that was answered an error runs: listed ones are exactly the ok ones.
    assert ids(name) == Enum.sort(ok)

    pids = for a <- Tartarus.agents(name), do: a.pid
    :ok = Tartarus.stop_host(name)
    assert {:ok, _} = wait_for(fn -> not Enum.any?(pids, &Process.alive?/1) end)
    assert Enum.filter(Tartarus.agents(), &(&1.host == addr(name))) == []
  end

  test "Tartarus.agents/0 lists only agents that exist: none of a stopped host's" do
    name = unique_name()
    {:ok, _} = Tartarus.start_host(name)
    for _ <- 1..10, do: agent!(name, %{count: 0})
    assert length(Enum.filter(Tartarus.agents(), &(&1.host == addr(name)))) == 10
    :ok = Tartarus.stop_host(name)
    assert Enum.filter(Tartarus.agents(), &(&1.host == addr(name))) == []
    assert :ets.match(Tartarus.AgentTable, {:_, :_, name, :_, :_}) == []
  end

  # The flush of a host's acknowledgements is a timer sent to its server, armed once
  # (Arrival.ack/4 sets host.acks_armed, which the warden owns). A server killed before that
  # timer fires takes it along and the flag stays set: unless the restarted server flushes as
  # it starts, no later arrival arms the timer again and no source hears from this host again
  # (its commits stay unacknowledged, its pointers never sweepable). Failed before the fix.
  test "an arrival's acknowledgement reaches its source when the destination's server is killed before it flushes" do
    [a, b] = [host!(), host!()]
    :ok = Tartarus.connect(a, b)
    x = agent!(a, %{count: 0})
    y = agent!(a, %{count: 0})

    # The flush timer's message waits in b's suspended server, which is then killed with it.
    {:ok, server} = Tartarus.Host.whereis(addr(b))
    :ok = :sys.suspend(server)
    :ok = Tartarus.move({x, addr(a)}, b)
    assert :atomics.get(local!(b).acks_armed, 1) == 1
    :ok = kill_server!(b)

    # One more arrival after the restart.
    :ok = Tartarus.move({y, addr(a)}, b)
    acked = fn id -> {id, addr(b), :acked} in Tartarus.Ledger.pointers(local!(a)) end
    assert eventually(fn -> acked.(x) and acked.(y) end, 5_000)
  end

  defp local!(name) do
    {:ok, info} = Tartarus.Host.local(name)
    info
  end
end
