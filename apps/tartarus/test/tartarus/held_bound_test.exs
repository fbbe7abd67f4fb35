defmodule Tartarus.HeldBoundTest do
  # An agent mid-hand-off (its destination's admission held at `:admitting`, so the prepare
  # waits) holds
  # a bounded amount of what it is sent: at most :max_held events and :max_held_bytes bytes,
  # binaries included; the overflow is refused to its senders ({:error, {:overloaded, id}})
  # instead of the agent being killed. Before, 64 KiB binaries piled up without bound (they
  # live off the heap: max_heap_size never fired) and a flood of small messages got the
  # agent heap-killed and restarted from its snapshot, reverting posts answered :ok.
  use Tartarus.HostCase, async: false

  # `n` senders, each posting `msg_of.(i)` once: results come as {:posted, result}.
  defp flood(id, h, n, msg_of) do
    test = self()

    for i <- 1..n,
        do:
          spawn(fn -> send(test, {:posted, Tartarus.post({id, addr(h)}, msg_of.(i), 30_000)}) end)

    :ok
  end

  # The next `n` results.
  defp results(n) do
    for _ <- 1..n do
      receive do
        {:posted, result} -> result
      after
        30_000 -> flunk("a sender did not return")
      end
    end
  end

  # Starts a move of agent `id` from `a` to `b` whose admission at `b` is held before it
  # creates the copy (the move waits); returns the move's task and a function that lets the
  # admission go on.
  defp stalled_move(id, a, b) do
    :ok = Tartarus.Fault.install(:admitting, {:once, {:pause, self()}})
    on_exit(fn -> Tartarus.Fault.clear(:admitting) end)
    task = Task.async(fn -> Tartarus.move({id, addr(a)}, b) end)
    [%{pid: pid}] = Tartarus.agents(a)
    assert_receive {:fault_paused, :admitting, admitting, _env}, 10_000
    {:ok, _} = wait_for(fn -> match?({:handing_off, _}, :sys.get_state(pid)) end)
    {task, fn -> Tartarus.Fault.continue(admitting) end, pid}
  end

  test "64 KiB binaries sent to a handing-off agent: held bytes bounded, the rest refused" do
    a = host!(migration_timeout: 2_000, max_held_bytes: 1_048_576)
    b = host!()
    :ok = Tartarus.connect(a, b)
    id = agent!(a, %{count: 0})
    {task, resume, pid} = stalled_move(id, a, b)

    blob = :binary.copy(<<7>>, 65_536)

    :ok = flood(id, a, 100, &{:set, &1, blob})

    # Every sender beyond the bound is answered at once, while the move still waits.
    early = results(84)
    assert Enum.all?(early, &match?({:error, {:overloaded, ^id}}, &1))
    # What it holds (the refused ones are garbage once collected).
    true = :erlang.garbage_collect(pid)
    held = pid |> Process.info(:binary) |> elem(1) |> Enum.map(&elem(&1, 1)) |> Enum.sum()
    assert held <= 1_048_576 + 65_536
    assert {:handing_off, _} = :sys.get_state(pid)

    resume.()
    Task.await(task, 10_000)
    late = results(16)
    # 1 MiB holds 15 of them (each a little over 64 KiB): those are taken once the move
    # ends (a sender that came after it ended is taken too); none was lost.
    assert Enum.count(late, &(&1 == :ok)) >= 15
    assert Enum.all?(late, &(&1 == :ok or match?({:error, {:overloaded, ^id}}, &1)))
  end

  test "a flood of small messages: refused beyond the bound, no acknowledged post reverted" do
    a = host!(migration_timeout: 3_000, max_heap_size: 100_000, max_held: 1_000)
    b = host!()
    :ok = Tartarus.connect(a, b)
    id = agent!(a, %{count: 0})
    {task, resume, pid} = stalled_move(id, a, b)

    # 10,000 senders, one post of :inc each, all at once.
    :ok = flood(id, a, 10_000, fn _ -> :inc end)
    early = results(9_000)
    assert Enum.all?(early, &match?({:error, {:overloaded, ^id}}, &1))
    # Not heap-killed (before, the agent was killed and restarted from its snapshot).
    assert {:handing_off, _} = :sys.get_state(pid)

    resume.()
    Task.await(task, 10_000)
    late = results(1_000)
    ok = Enum.count(late, &(&1 == :ok))
    assert ok == 1_000

    # Every post answered :ok is in the agent's count, wherever it is now.
    [where] = Enum.filter([a, b], &(Tartarus.agents(&1) != []))
    assert {:ok, %{count: ^ok}} = Tartarus.request({id, addr(where)}, :state)
  end

  # A sender follows the agent and sends its message again to the agent's next process
  # (Tartarus.Locator): a copy of a message already handed over and taken. Such copies
  # reached a handing-off agent by the hundred (every waiting sender, at every hop) and
  # filled its bound, so new messages were refused (the busy benchmark with --cast: 1,805
  # of 10,000 refused) and their senders told a failure. Now a copy of a taken message is
  # dropped, unanswered and uncounted.
  test "copies of messages taken already do not count against the bound" do
    a = host!(migration_timeout: 3_000, max_held: 2)
    b = host!()
    :ok = Tartarus.connect(a, b)
    id = agent!(a, %{count: 0})
    [%{pid: first}] = Tartarus.agents(a)

    # Taken by the agent (as a sender's first copy is).
    send(first, {:"$tartarus_msg", {self(), 7}, :post, :inc})
    assert_receive {7, :delivered}, 5_000

    {task, resume, pid} = stalled_move(id, a, b)
    assert pid == first
    # Five copies of it while the agent hands off: dropped, none answered.
    for _ <- 1..5, do: send(pid, {:"$tartarus_msg", {self(), 7}, :post, :inc})
    # Two new messages still fit in the bound of two.
    :ok = flood(id, a, 2, fn _ -> :inc end)
    refute_receive {7, _}, 300

    resume.()
    Task.await(task, 10_000)
    assert results(2) == [:ok, :ok]
    refute_received {7, _}
    assert {:ok, %{count: 3}} = Tartarus.request({id, addr(b)}, :state)
  end
end
