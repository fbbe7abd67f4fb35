defmodule Tartarus.Migration.ServersRobustnessTest do
  # The host and agent servers against messages nobody should send them (issue 9, item 1,
  # for these two servers): dropped and counted, never a crash; a forged :DOWN changes
  # nothing; paused copies count against admission.
  use Tartarus.HostCase, async: false

  alias Tartarus.{CodeCache, Envelope, Ledger}
  alias Tartarus.Examples.Echo
  alias Tartarus.Migration.Messages

  defp dropped(host) do
    {:ok, h} = Tartarus.Host.local(host)
    Ledger.counted(h, :dropped)
  end

  defp agent_pid(host, id) do
    [%{pid: pid}] = Enum.filter(Tartarus.agents(host), &(&1.id == id))
    pid
  end

  test "casts, junk messages and :sweep without forward_ttl leave a host up and its agents reachable" do
    a = host!()
    {:ok, id} = Tartarus.create_mobile_agent(a, Echo, :kept)
    {:ok, pid} = Tartarus.Host.whereis(a)

    GenServer.cast(pid, :junk)
    send(pid, :sweep)
    send(pid, {:"$tartarus_decision?", :not, :a, :query, :at_all})
    send(pid, :hello)
    assert {:error, {:bad_message, :unknown_call}} = GenServer.call(pid, {:what, :ever})

    assert {:ok, ^pid} = Tartarus.Host.whereis(a)
    assert dropped(a) == 4
    assert {:ok, :kept} = Tartarus.request({id, a}, :state)
  end

  test "a forged :DOWN for a live agent changes nothing" do
    a = host!()
    {:ok, id} = Tartarus.create_mobile_agent(a, Echo, :alive)
    {:ok, server} = Tartarus.Host.whereis(a)
    apid = agent_pid(a, id)

    send(server, {:DOWN, make_ref(), :process, apid, :killed})

    assert GenServer.call(server, :monitored) == 1
    assert [%{id: ^id}] = Tartarus.agents(a)
    assert {:ok, :alive} = Tartarus.request({id, a}, :state)
  end

  test "junk calls, casts and malformed messages to an agent are answered or dropped, not a crash" do
    a = host!()
    {:ok, id} = Tartarus.create_mobile_agent(a, Echo, :steady)
    apid = agent_pid(a, id)

    for _ <- 1..5, do: assert({:error, :unexpected} = GenServer.call(apid, {:junk, self()}))
    GenServer.cast(apid, :junk)
    send(apid, {:"$tartarus_msg", {:not_a_pid, make_ref()}, :post, :x})
    send(apid, Messages.commit({"x", make_ref()}, :crypto.strong_rand_bytes(16), nil))

    assert {:ok, :steady} = Tartarus.request({id, a}, :state)
    assert agent_pid(a, id) == apid
  end

  test "paused copies count against max_resident_agents" do
    b = host!(admission: [max_resident_agents: 2])
    {:ok, server} = Tartarus.Host.whereis(b)
    {:ok, manifest} = CodeCache.manifest([Echo])

    # Prepares naming a source that never answers: each would leave a paused copy.
    replies =
      for n <- 1..3 do
        mig = {"incarnat", make_ref()}
        env = %Envelope{id: Envelope.new_id(), module: Echo, rng: Envelope.seed_rng(n)}

        send(
          server,
          Messages.prepare(self(), mig, {:nowhere, node()}, self(), :move, env, manifest, [])
        )

        receive do
          {:"$tartarus_prepared", ^mig, _copy, _pid} -> :prepared
          {:"$tartarus_refused", ^mig, reason} -> {:refused, reason}
        after
          2_000 -> :timeout
        end
      end

    assert [:prepared, :prepared, {:refused, _}] = replies
    assert Tartarus.Host.call(b, :paused) == 2
  end

  # Admission runs in one process per prepare (Tartarus.Host.Arrivals), all at once: what
  # they share is updated atomically in the host's ledger. Every admission that passed its
  # checks is held at `:admitting` (before it creates its copy) until all were sent, so
  # they overlap; then they go on.
  defp prepares_at_once(host, migs_envs) do
    {:ok, manifest} = CodeCache.manifest([Echo])
    :ok = Tartarus.Fault.install(:admitting, {:pause, self()})

    try do
      for {mig, env} <- migs_envs do
        prepare =
          Messages.prepare(self(), mig, {:nowhere, node()}, self(), :move, env, manifest, [])

        Tartarus.Host.Arrivals.send_prepare(host, self(), prepare)
      end

      held = paused([])
      Tartarus.Fault.clear(:admitting)
      Enum.each(held, &Tartarus.Fault.continue/1)
      {length(held), collect([])}
    after
      Tartarus.Fault.clear(:admitting)
    end
  end

  defp paused(acc) do
    receive do
      {:fault_paused, :admitting, pid, _env} -> paused([pid | acc])
    after
      500 -> acc
    end
  end

  defp collect(acc) do
    receive do
      {:"$tartarus_prepared", mig, copy, pid} -> collect([{:prepared, mig, copy, pid} | acc])
      {:"$tartarus_refused", mig, reason} -> collect([{:refused, mig, reason} | acc])
    after
      1_000 -> acc
    end
  end

  defp envelope(n), do: %Envelope{id: Envelope.new_id(), module: Echo, rng: Envelope.seed_rng(n)}

  test "concurrent prepares never take the same last place: max_resident_agents holds" do
    b = host!(admission: [max_resident_agents: 5])
    migs = for n <- 1..40, do: {{"incarnat", make_ref()}, envelope(n)}
    {held, replies} = prepares_at_once(b, migs)

    # Five places reserved while all forty were being admitted; the others refused.
    assert held == 5
    assert length(replies) == 40
    assert Enum.count(replies, &match?({:prepared, _, _, _}, &1)) == 5
    assert Enum.count(replies, &match?({:refused, _, {:too_many_agents, 5}}, &1)) == 35
    assert Tartarus.Host.call(b, :paused) == 5
    # The host's server adopted the copies (asynchronously).
    {:ok, server} = Tartarus.Host.whereis(b)
    eventually(fn -> GenServer.call(server, :monitored) == 5 end)
  end

  test "concurrent copies of one prepare make one paused copy" do
    b = host!()
    mig = {"incarnat", make_ref()}
    {held, replies} = prepares_at_once(b, List.duplicate({mig, envelope(1)}, 20))

    # The first claims it; the others meet its claim (dropped: it answers) or, once it
    # made its copy, that copy (the same answer again).
    assert held == 1
    assert [{:prepared, ^mig, copy, pid} | _] = replies
    assert Enum.all?(replies, &(&1 == {:prepared, mig, copy, pid}))
    assert Tartarus.Host.call(b, :paused) == 1
  end
end

defmodule Tartarus.Migration.ParkingTest do
  # A paused copy whose source does not answer parks (Tartarus.Migration.CopyProtocol.step/2):
  # its process goes, the host keeps its record and revives or drops it only on the source's
  # answer.
  use Tartarus.HostCase, async: false

  alias Tartarus.{CodeCache, Envelope, Ledger}
  alias Tartarus.Examples.Echo
  alias Tartarus.Migration.Messages

  # A prepare from `a` (its incarnation, no hand-off there) admitted by `b`: the paused copy.
  defp paused_copy(a, b) do
    {:ok, ha} = Tartarus.Host.local(a)
    {:ok, server} = Tartarus.Host.whereis(b)
    {:ok, manifest} = CodeCache.manifest([Echo])
    mig = {ha.incarnation, make_ref()}

    env = %Envelope{
      id: Envelope.new_id(),
      module: Echo,
      state: :parked,
      rng: Envelope.seed_rng(1)
    }

    send(server, Messages.prepare(self(), mig, {a, node()}, self(), :move, env, manifest, []))
    assert_receive {:"$tartarus_prepared", ^mig, copy, pid}, 2_000
    {ha, server, mig, copy, pid, env.id}
  end

  # Its queries are answered :unknown meanwhile (a hand-off record of `mig` of agent `id` at
  # the source). With `keep_handoff: true` the source stays undecided afterwards (its record
  # stays).
  defp park(ha, pid, mig, id, opts \\ []) do
    Ledger.begin_handoff(ha, id, mig)
    ref = Process.monitor(pid)

    # Its next state timeout (the destination's migration_timeout) is its last unanswered
    # ask: it parks then.
    :sys.replace_state(pid, fn {state, data} ->
      {state, put_in(data.paused.c.asks, data.paused.c.park_after)}
    end)

    assert_receive {:DOWN, ^ref, :process, ^pid, {:shutdown, :parked}}, 5_000
    unless opts[:keep_handoff], do: Ledger.end_handoff(ha, id, mig)
  end

  # A copy parked at a fresh host b, then committed at its source (in the protocol's order:
  # the decision before the hand-off record goes), with no answer sent yet.
  defp parked_and_committed do
    [a, b] = [host!(), host!(migration_timeout: 200)]
    {ha, server, mig, copy, pid, id} = paused_copy(a, b)
    park(ha, pid, mig, id, keep_handoff: true)
    Ledger.decide(ha, mig, {:committed, copy})
    Ledger.end_handoff(ha, id, mig)
    {b, server, mig, copy, id}
  end

  # Kills host b's server and waits for the one started in its place.
  defp kill_server(b, server) do
    Process.exit(server, :kill)
    restarted = fn -> match?({:ok, p} when p != server, Tartarus.Host.whereis(b)) end
    assert eventually(restarted, 5_000)
  end

  test "a parked copy is revived on a committed answer and runs once" do
    [a, b] = [host!(), host!(migration_timeout: 200)]
    {ha, server, mig, copy, pid, id} = paused_copy(a, b)
    park(ha, pid, mig, id, keep_handoff: true)
    assert Tartarus.Host.call(b, :parked) == 1 and Tartarus.Host.call(b, :paused) == 0

    # Unknown (the source has a hand-off record): kept.
    send(server, :"$tartarus_ask_parked")
    assert Tartarus.Host.call(b, :parked) == 1

    # Committed to this copy: revived, it starts. Written in the protocol's order (the
    # decision before the hand-off record goes): the query above may still be answered
    # meanwhile, and between the two steps in the other order it would read "aborted".
    Ledger.decide(ha, mig, {:committed, copy})
    Ledger.end_handoff(ha, id, mig)
    send(server, :"$tartarus_ask_parked")
    assert eventually(fn -> Enum.any?(Tartarus.agents(b), &(&1.id == id)) end, 2_000)
    assert Tartarus.Host.call(b, :parked) == 0
    assert {:ok, :parked} = Tartarus.request({id, b}, :state)
  end

  test "a paused copy with a full stash tells a sender to send again, and takes it once it runs" do
    [a, b] = [host!(), host!(migration_timeout: 200)]
    {_ha, _server, mig, copy, pid, id} = paused_copy(a, b)
    # The stash holds 1,000 messages; what comes after is not kept.
    for i <- 1..1_000, do: send(pid, {:filler, i})
    tag = System.unique_integer([:monotonic, :positive])
    send(pid, {:"$tartarus_msg", {self(), tag}, :post, :late})
    assert_receive {^tag, :retry}, 2_000

    # Committed: the copy runs; sent again, the message is taken.
    send(pid, Messages.commit(mig, copy, nil))
    assert eventually(fn -> Enum.any?(Tartarus.agents(b), &(&1.id == id)) end, 2_000)
    send(pid, {:"$tartarus_msg", {self(), tag}, :post, :late})
    assert_receive {^tag, :delivered}, 2_000
  end

  # The host asks about its parked copies on a timer sent to its server, armed when the first
  # copy parks (count 1). A server killed meanwhile takes the timer along; the records live on
  # in the warden's ledger, and unless the restarted server asks as it starts (the count
  # above 0, no later park arms the timer again) the copy is never revived while the host
  # lives. Failed before the fix.
  test "a parked copy is revived after its host's server is killed" do
    {b, server, _mig, _copy, id} = parked_and_committed()
    assert Tartarus.Host.call(b, :parked) == 1

    kill_server(b, server)
    assert eventually(fn -> Enum.any?(Tartarus.agents(b), &(&1.id == id)) end, 5_000)
    assert Tartarus.Host.call(b, :parked) == 0
  end

  # Its server dies as it is about to revive the copy (a fault point stops it there): the
  # record must outlive it. Failed before the revived copy took its record itself (the
  # server forgot the record first, then started the copy: killed in between, the agent was
  # gone while its host lived).
  test "a parked copy is revived when its host's server dies while reviving it" do
    {b, server, mig, copy, id} = parked_and_committed()

    Tartarus.Fault.install(:reviving, {:once, {:pause, self()}})
    on_exit(fn -> Tartarus.Fault.clear(:reviving) end)
    send(server, :"$tartarus_ask_parked")
    assert_receive {:fault_paused, :reviving, ^server, {^mig, ^copy}}, 2_000
    kill_server(b, server)

    assert eventually(fn -> Enum.any?(Tartarus.agents(b), &(&1.id == id)) end, 5_000)
    assert eventually(fn -> Tartarus.Host.call(b, :parked) == 0 end, 2_000)
    assert length(Enum.filter(Tartarus.agents(), &(&1.id == id))) == 1
  end

  # Two copies revived from one record (a server that died after starting the first, and
  # the one started in its place, which asked again): the first to take the record runs, the
  # other stops.
  test "of two copies revived from one parked record one runs" do
    {b, server, mig, copy, id} = parked_and_committed()

    # The server handles both answers before either copy takes the record.
    :sys.suspend(server)
    for _ <- 1..2, do: send(server, {:"$tartarus_decision", mig, copy, {:committed, nil}})
    :sys.resume(server)

    assert eventually(fn -> Enum.any?(Tartarus.agents(b), &(&1.id == id)) end, 5_000)
    assert eventually(fn -> Tartarus.Host.call(b, :paused) == 0 end, 2_000)
    assert Tartarus.Host.call(b, :parked) == 0
    assert length(Enum.filter(Tartarus.agents(), &(&1.id == id))) == 1
  end

  test "a parked copy is dropped on an aborted answer" do
    [a, b] = [host!(), host!(migration_timeout: 200)]
    {ha, server, mig, _copy, pid, id} = paused_copy(a, b)
    park(ha, pid, mig, id)
    send(server, :"$tartarus_ask_parked")
    assert eventually(fn -> Tartarus.Host.call(b, :parked) == 0 end, 2_000)
    assert Tartarus.agents(b) == []
    assert {:error, :not_found} = Tartarus.request({id, b}, :state)
  end

  test "only the copy itself may park its record" do
    b = host!()
    {:ok, server} = Tartarus.Host.whereis(b)
    env = %Envelope{id: Envelope.new_id(), module: Echo, rng: Envelope.seed_rng(1)}
    mig = {"incarnat", make_ref()}
    copy = :crypto.strong_rand_bytes(16)

    assert {:error, :not_paused_here} =
             GenServer.call(server, {:park, mig, copy, env, {:x, node()}, :move})

    assert Tartarus.Host.call(b, :parked) == 0
  end
end
