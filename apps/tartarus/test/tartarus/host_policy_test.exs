defmodule Tartarus.HostPolicyTest do
  # Host options that protect a host: admission policy, per-agent heap limit, and
  # persistence across a host restart (in this VM; the multi-node kills are in test/).
  use Tartarus.HostCase, async: false

  test "an admission policy refuses arrivals beyond its limits, and the agent stays home" do
    a = host!()
    b = host!(admission: [max_resident_agents: 1, max_hops: 2])
    :ok = Tartarus.connect(a, b)
    [one, two] = for _ <- 1..2, do: agent!(a)

    assert :ok = Tartarus.move({one, a}, b)
    assert {:error, {:too_many_agents, 1}} = Tartarus.move({two, a}, b)
    assert {:ok, {^a, _}} = Tartarus.whereis({two, a})
    assert Tartarus.status(b).counts.refused == 1

    # Hops: one has made 1 hop; coming back to b would be its 3rd.
    assert :ok = Tartarus.move({one, b}, a)
    :ok = Tartarus.kill({two, a})
    assert {:error, {:ttl_expired, 3}} = Tartarus.move({one, a}, b)
  end

  # Admission runs beside the host's server, off its queue (Tartarus.Host.Arrivals), and
  # counts the host's agents from the ledger. An agent that moves away is no longer counted
  # once it left, however far behind its :DOWN the host's server is; and a server that
  # takes an adoption late does not count again a copy that already left. (With a thousand
  # agents moving, both made a host refuse arrivals {:too_many_agents, _} while it held half
  # its limit: agents of the churn benchmark stopped moving.)
  test "agents that left are not counted, however far behind the host's server is" do
    a = host!(admission: [max_resident_agents: 3])
    b = host!()
    :ok = Tartarus.connect(a, b)
    [one, two] = for _ <- 1..2, do: agent!(a)
    three = agent!(b)

    server =
      while_suspended(a, fn ->
        # Both leave while a's server takes nothing (their :DOWNs wait in its mailbox).
        assert :ok = Tartarus.move({one, a}, b)
        assert :ok = Tartarus.move({two, a}, b)
        # Three arrive: a holds none of its three places.
        for id <- [one, two, three], do: assert(:ok = Tartarus.move({id, b}, a))
        # And leave again before a's server adopted them.
        for id <- [one, two], do: assert(:ok = Tartarus.move({id, a}, b))
      end)

    # The server caught up (adoptions, :DOWNs): a holds one agent, two places are free.
    {:ok, _} = wait_for(fn -> length(Tartarus.agents(a)) == 1 end)
    _ = :sys.get_state(server)
    assert :ok = Tartarus.move({one, b}, a)
    assert :ok = Tartarus.move({two, b}, a)
    assert {:error, {:too_many_agents, 3}} = Tartarus.move({agent!(b), b}, a)
  end

  # The same for agents that end by their own choice (stop, return): the churn benchmark's
  # agents end after their hops, and with persistence the host's server fell a thousand
  # :DOWNs behind within three batches; arrivals were refused while the host held nobody.
  test "agents that ended are not counted, however far behind the host's server is" do
    a = host!(admission: [max_resident_agents: 2])
    b = host!()
    :ok = Tartarus.connect(a, b)
    [one, two] = for _ <- 1..2, do: agent!(a)
    three = agent!(b)

    while_suspended(a, fn ->
      assert {:ok, :ok} = Tartarus.request({one, a}, {:do, {:stop, :done}})
      assert {:ok, :ok} = Tartarus.request({two, a}, {:do, {:return, :done}})

      {:ok, _} =
        wait_for(fn -> Enum.all?([one, two], &(Tartarus.whereis({&1, a}) != {:ok, a})) end)

      assert :ok = Tartarus.move({three, b}, a)
    end)

    assert {:ok, {^a, _}} = Tartarus.whereis({three, a})
  end

  # Runs `fun` while host's server takes nothing (its mailbox waits); returns the server.
  defp while_suspended(host, fun) do
    {:ok, server} = Tartarus.Host.whereis(host)
    :ok = :sys.suspend(server)

    try do
      fun.()
    after
      :ok = :sys.resume(server)
    end

    server
  end

  test "bad admission options are refused with the option named" do
    assert Tartarus.start_host(unique_name(), admission: [max_hops: -1]) ==
             {:error,
              "invalid options given to Tartarus.start_host/2 for key [:admission, :max_hops]: " <>
                "expected a positive integer or :infinity, got: -1"}

    assert Tartarus.start_host(unique_name(), admission: [max_agents: 3]) ==
             {:error,
              "invalid options given to Tartarus.start_host/2 for key :admission: unknown key " <>
                ":max_agents, known keys: #{inspect(Keyword.keys(Tartarus.Security.Admission.schema()))}"}
  end

  test "bad security options are refused with the key path named" do
    assert Tartarus.start_host(unique_name(), security: [keys: :nope]) ==
             {:error,
              "invalid options given to Tartarus.start_host/2 for key [:security, :keys]: " <>
                "expected a key pair from Tartarus.Security.Keys.generate/0, got: :nope"}

    assert Tartarus.start_host(unique_name(), security: [trust: []]) ==
             {:error,
              "invalid options given to Tartarus.start_host/2 for key [:security, :trust]: " <>
                "expected a %Tartarus.Security.TrustList{}, got: []"}
  end

  test "an agent that outgrows max_heap_size is killed, restarted, then removed" do
    a = host!(max_heap_size: 50_000, max_restarts: 1)
    id = agent!(a, %{}, owner: self())
    {:ok, pid, _} = Tartarus.AgentTable.lookup(id)
    ref = Process.monitor(pid)
    send(pid, {:grow, 1_000_000})
    assert_receive {:DOWN, ^ref, :process, ^pid, :killed}, 5_000

    # Restarted once from its snapshot (max_restarts: 1); killed again, it is removed.
    assert eventually(fn -> match?({:ok, p, _} when p != pid, Tartarus.AgentTable.lookup(id)) end)
    {:ok, pid2, _} = Tartarus.AgentTable.lookup(id)
    send(pid2, {:grow, 1_000_000})
    assert_receive {:tartarus_removed, ^id, {:too_many_restarts, :killed}}, 5_000
  end

  test "with a data directory, a host restarted on it gets its agents back" do
    dir = Path.join(System.tmp_dir!(), "policy_#{System.unique_integer([:positive])}")
    name = unique_name()
    {:ok, h} = Tartarus.start_host(name, data_dir: dir)
    ids = for n <- 1..3, do: elem(Tartarus.create_mobile_agent(h, Tartarus.Examples.Echo, n), 1)
    {:ok, gone} = Tartarus.create_mobile_agent(h, Tartarus.Examples.Echo, :bye)
    :ok = Tartarus.kill({gone, h})
    :ok = Tartarus.stop_host(h)
    assert Tartarus.agents(h) == {:error, {:unknown_host, h}}

    {:ok, ^h} = Tartarus.start_host(name, data_dir: dir)
    restored = h |> Tartarus.agents() |> Enum.map(& &1.id) |> Enum.sort()
    assert restored == Enum.sort(ids)
    assert {:ok, 2} = Tartarus.request({Enum.at(ids, 1), h}, :state)
    :ok = Tartarus.stop_host(h)
    File.rm_rf!(dir)
  end

  test "forward_ttl sweeps old forwarding pointers; without it they stay" do
    a = host!(forward_ttl: 50)
    b = host!()
    :ok = Tartarus.connect(a, b)
    id = agent!(a)
    :ok = Tartarus.move({id, a}, b)
    assert Tartarus.status(a).forwarding_pointers >= 1
    assert eventually(fn -> Tartarus.status(a).forwarding_pointers == 0 end, 2_000)
    assert {:error, :not_found} = Tartarus.whereis({id, a})
    assert {:ok, {^b, _}} = Tartarus.whereis({id, b})

    :ok = Tartarus.move({id, b}, a)
    # Not an ordering: time passes (twice a's ttl) and b, without forward_ttl, keeps its pointer.
    Process.sleep(100)
    assert Tartarus.status(b).forwarding_pointers >= 1
  end
end
