defmodule Tartarus.AgentProcessTest do
  # The agent's process (issue 43, item 4): no platform key in its dictionary outside its
  # callbacks (the host's watchdog reads the ledger, not the agent's dictionary); in
  # :handing_off its messages are held and every other event postponed, together bounded by
  # the hop's stash bound, which is also the paused copy's; and the one deviation from OTP's
  # process conventions it keeps (a plain spawn entering gen_statem as its own parent, not
  # proc_lib: Tartarus.Agent.Server.enter/4), pinned: :sys works on it, a crash is logged
  # once by its host and by nothing in its own process, and stopping its host or killing it
  # ends it within its budget.
  use Tartarus.HostCase, async: false

  alias Tartarus.Ledger

  defmodule Blocker do
    @moduledoc false
    # Reports to `test`. Messages: :keys (replies with the platform's keys in its dictionary
    # as a callback sees them), :block (stays in the callback until it receives :release),
    # :crash (raises), :inc. With `trap: true` it traps exits.
    use Tartarus.Agent

    @impl true
    def init(%{test: _} = s) do
      if s[:trap], do: Process.flag(:trap_exit, true)
      {:stay, Map.put(s, :count, 0)}
    end

    @impl true
    def handle_message(:keys, from, s) do
      Tartarus.Agent.reply(from, Tartarus.AgentProcessTest.platform_keys(Process.get()))
      {:stay, s}
    end

    def handle_message(:block, _from, %{test: test} = s) do
      send(test, {:blocked, self()})

      receive do
        :release -> {:stay, s}
      end
    end

    def handle_message(:crash, _from, _s), do: raise("crash on purpose")
    def handle_message(:inc, _from, s), do: {:stay, %{s | count: s.count + 1}}

    def handle_message(:count, from, s) do
      Tartarus.Agent.reply(from, s.count)
      {:stay, s}
    end
  end

  @doc false
  # The keys of a process dictionary that the platform would own ("$tartarus..." atoms).
  def platform_keys(dict) do
    for {k, _} <- dict, is_atom(k), String.starts_with?(Atom.to_string(k), "$tartarus"), do: k
  end

  defp dict_keys(pid), do: pid |> Process.info(:dictionary) |> elem(1) |> platform_keys()

  defp pid_of(id) do
    {:ok, %{pid: pid}} = Tartarus.agent_info(id)
    pid
  end

  defp host_map(h) do
    {:ok, host} = Tartarus.Host.local(addr(h))
    host
  end

  # A move of agent `id` from `a` to `b` whose destination's server is suspended (the move
  # waits in :handing_off); returns the move's task, a function that resumes the
  # destination and the agent's process.
  # A move from a to b whose prepare waits at the destination (the admitting process paused
  # at the fault point :prepare_received) until the returned function releases it.
  defp stalled_move(id, a, b) do
    Tartarus.Fault.install(:prepare_received, {:once, {:pause, self()}})
    on_exit(fn -> Tartarus.Fault.clear(:prepare_received) end)
    pid = pid_of(id)
    task = Task.async(fn -> Tartarus.move({id, addr(a)}, b) end)
    assert_receive {:fault_paused, :prepare_received, admitting, _}, 5_000
    {:ok, _} = wait_for(fn -> match?({:handing_off, _}, :sys.get_state(pid)) end)
    {task, fn -> Tartarus.Fault.continue(admitting) end, pid}
  end

  describe "process dictionary" do
    test "an agent keeps no platform key between callbacks, one (its context) inside them" do
      a = host!()
      b = host!()
      :ok = Tartarus.connect(a, b)
      {:ok, id} = Tartarus.create_agent(a, Blocker, %{test: self()})
      assert dict_keys(pid_of(id)) == []
      assert {:ok, [:"$tartarus_agent"]} = Tartarus.request(id, :keys)
      assert dict_keys(pid_of(id)) == []

      # Handing off (its destination stalled), then arrived: still none.
      {task, resume, pid} = stalled_move(id, a, b)
      assert dict_keys(pid) == []
      resume.()
      assert :ok = Task.await(task, 10_000)
      assert {:ok, [:"$tartarus_agent"]} = Tartarus.request(id, :keys)
      assert dict_keys(pid_of(id)) == []
    end

    test "a clone's id leaves no key in the source's dictionary" do
      a = host!()
      b = host!()
      :ok = Tartarus.connect(a, b)
      {:ok, id} = Tartarus.create_agent(a, Blocker, %{test: self()})
      assert {:ok, _clone} = Tartarus.clone(id, b)
      assert dict_keys(pid_of(id)) == []
    end

    @scope ["migration/*.ex", "agent/*.ex", "host/*.ex", "ledger.ex", "locator.ex"]
    # What may stay: the pinned deviation's start (enter/4 names the process's parent and
    # initial call, OTP's keys) and the logger filter that reads OTP's initial call in the
    # agent's own process (Host.Agents.drop_agent_report/2).
    @allowed [
      ~S|Process.put(:"$ancestors", [host.warden])|,
      ~S|Process.put(:"$initial_call", {__MODULE__, :init, 1})|,
      ~S|Process.get(:"$initial_call") == {Tartarus.Agent.Server, :init, 1}|
    ]

    test "the migration path and the host's reads of agents use no process-dictionary key" do
      lib = Path.expand("../../lib/tartarus", __DIR__)
      files = Enum.flat_map(@scope, &Path.wildcard(Path.join(lib, &1)))
      assert length(files) > 20

      found =
        for file <- files,
            {line, n} <- Enum.with_index(String.split(File.read!(file), "\n"), 1),
            not String.starts_with?(String.trim_leading(line), "#"),
            line =~
              ~r/Process\.(put|get|delete|get_keys)\b|:dictionary\b|:erlang\.(put|get|erase)\(/,
            not Enum.any?(@allowed, &String.contains?(line, &1)),
            do: "#{Path.relative_to(file, lib)}:#{n}: #{String.trim(line)}"

      assert found == []
    end
  end

  describe "the watchdog's entry" do
    test "is in the host's ledger while a callback runs under its budget, gone after it" do
      h = host!(callback_timeout: 60_000)
      {:ok, id} = Tartarus.create_agent(h, Blocker, %{test: self()})
      pid = pid_of(id)
      assert Ledger.watchdog(host_map(h), pid) == nil
      assert :ok = Tartarus.post(id, :block)
      assert_receive {:blocked, ^pid}
      assert {tref, :handle_message, 60_000, nil} = Ledger.watchdog(host_map(h), pid)
      assert is_reference(tref)
      send(pid, :release)
      assert {:ok, 0} = Tartarus.request(id, :count)
      assert Ledger.watchdog(host_map(h), pid) == nil
    end

    test "of an agent killed inside a callback goes with it" do
      h = host!(callback_timeout: 60_000)
      {:ok, id} = Tartarus.create_agent(h, Blocker, %{test: self()})
      pid = pid_of(id)
      assert :ok = Tartarus.post(id, :block)
      assert_receive {:blocked, ^pid}
      assert :ok = Tartarus.kill(id)
      refute Process.alive?(pid)
      assert {:ok, true} = wait_for(fn -> Ledger.watchdog(host_map(h), pid) == nil end)
    end

    test "of an agent that overran is read by the watchdog, which stops it" do
      h = host!(callback_timeout: 200)
      {:ok, id} = Tartarus.create_agent(h, Blocker, %{test: self()}, owner: self())
      pid = pid_of(id)
      mref = Process.monitor(pid)
      assert :ok = Tartarus.post(id, :block)
      assert_receive {:blocked, ^pid}

      assert_receive {:DOWN, ^mref, :process, ^pid, {:callback_timeout, :handle_message, 200}},
                     5_000

      assert_receive {:tartarus_removed, ^id, {:callback_timeout, :handle_message, 200}}, 5_000
      assert Ledger.watchdog(host_map(h), pid) == nil
    end
  end

  describe ":handing_off" do
    test "a call is postponed, not held, and answered once the hand-off failed" do
      a = host!(migration_timeout: 1_000)
      b = host!()
      :ok = Tartarus.connect(a, b)
      {:ok, id} = Tartarus.create_agent(a, Blocker, %{test: self()})
      {move, resume, pid} = stalled_move(id, a, b)

      info = Task.async(fn -> Tartarus.agent_info(id) end)
      post = Task.async(fn -> Tartarus.post(id, :inc, 30_000) end)

      {:ok, data} =
        wait_for(fn ->
          {:handing_off, data} = :sys.get_state(pid)
          if elem(data.postponed, 0) == 1 and length(data.held) == 1, do: data
        end)

      # The agent's message is held (it would travel with a commit); the call is not.
      assert [{:"$tartarus_msg", _, :post, :inc}] = data.held
      {:status, ^pid, _, [_pdict, _sysstate, _parent, _debug, misc]} = :sys.get_status(pid)
      assert inspect(misc) =~ "postponed"

      # The destination answers too late: the move fails, the held message is handled,
      # then the postponed call is answered (by this process, still the agent).
      assert {:error, _} = Task.await(move, 10_000)
      resume.()
      assert :ok = Task.await(post, 10_000)
      assert {:ok, %{pid: ^pid}} = Task.await(info, 10_000)
      assert {:ok, 1} = Tartarus.request(id, :count)
      assert {:running, %{held: [], postponed: {0, 0}}} = :sys.get_state(pid)
    end

    test "held messages and postponed events share the hop's stash bound" do
      a = host!(migration_timeout: 2_000, max_held: 2)
      b = host!()
      :ok = Tartarus.connect(a, b)
      {:ok, id} = Tartarus.create_agent(a, Blocker, %{test: self()})
      {move, resume, pid} = stalled_move(id, a, b)

      calls = for _ <- 1..2, do: Task.async(fn -> Tartarus.agent_info(id) end)

      {:ok, _} =
        wait_for(fn -> match?({:handing_off, %{postponed: {2, _}}}, :sys.get_state(pid)) end)

      # Two events kept: a post is refused at once, while the move still waits.
      assert {:error, {:overloaded, ^id}} = Tartarus.post(id, :inc, 30_000)
      assert {:handing_off, %{held: []}} = :sys.get_state(pid)

      resume.()
      Task.await(move, 10_000)
      Enum.each(calls, &assert({:ok, %{id: ^id}} = Task.await(&1, 20_000)))
    end

    test "the paused copy stashes at most the same bound (the host option :max_held)" do
      host = %{opts: %{max_held: 7, max_held_bytes: 1_000}}
      assert Tartarus.Migration.Arrival.stash_bound(host) == {7, 1_000}
      paused = Tartarus.Migration.Arrival.paused(host, :mig, :copy, :src, :move, nil)
      assert paused.c.stash_max == 7
    end
  end

  describe "started without proc_lib (the deviation, pinned)" do
    test ":sys reads and suspends an agent, whose parent is its host's warden" do
      h = host!()
      {:ok, id} = Tartarus.create_agent(h, Blocker, %{test: self()})
      pid = pid_of(id)
      warden = host_map(h).warden

      assert {:running, %{env: %{id: ^id}}} = :sys.get_state(pid)

      assert {:status, ^pid, {:module, :gen_statem}, [pdict, :running, ^warden, _debug, _]} =
               :sys.get_status(pid)

      assert pdict[:"$initial_call"] == {Tartarus.Agent.Server, :init, 1}
      assert pdict[:"$ancestors"] == [warden]
      assert :proc_lib.translate_initial_call(pid) == {Tartarus.Agent.Server, :init, 1}

      # Suspended, it takes no message; resumed, it takes them.
      :ok = :sys.suspend(pid)
      request = Task.async(fn -> Tartarus.request(id, :count, 30_000) end)
      assert Task.yield(request, 200) == nil
      :ok = :sys.resume(pid)
      assert {:ok, 0} = Task.await(request)
    end

    test "a stray exit message naming the agent itself does not stop it" do
      h = host!()
      {:ok, id} = Tartarus.create_agent(h, Blocker, %{test: self()})
      pid = pid_of(id)
      send(pid, {:EXIT, pid, :stray})
      # Taken in order: once it answers a later request, the stray message was handled.
      assert {:ok, 0} = Tartarus.request(id, :count)
      assert {:ok, %{pid: ^pid}} = Tartarus.agent_info(id)
    end

    test "a crash is logged once, by its host: nothing from the agent's own process" do
      h = host!()
      {:ok, id} = Tartarus.create_agent(h, Blocker, %{test: self()})
      pid = pid_of(id)
      :ok = :logger.add_handler(:agent_process_spy, Tartarus.Test.LogSpy, %{config: self()})
      on_exit(fn -> :logger.remove_handler(:agent_process_spy) end)

      assert {:error, {:agent_crashed, _}} = Tartarus.request(id, :crash, 60_000)
      # Restarted: the host has handled (and logged) the crash.
      {:ok, _} =
        wait_for(fn -> match?({:ok, %{pid: p}} when p != pid, Tartarus.agent_info(id)) end)

      :ok = :logger.remove_handler(:agent_process_spy)
      events = collect_logged([])

      assert [%{meta: meta}] = Enum.filter(events, &(inspect(&1.msg) =~ id))
      assert meta.pid != pid
      # No crash report (proc_lib's, gen_statem's) from the crashed process.
      assert Enum.filter(events, &(&1.meta[:pid] == pid)) == []
    end

    test "stopping its host ends an agent that traps exits, even inside a callback" do
      h = host!(callback_timeout: 60_000)
      {:ok, idle} = Tartarus.create_agent(h, Blocker, %{test: self(), trap: true})
      {:ok, stuck} = Tartarus.create_agent(h, Blocker, %{test: self(), trap: true})
      pids = [pid_of(idle), pid_of(stuck)]
      refs = Enum.map(pids, &Process.monitor/1)
      assert :ok = Tartarus.post(stuck, :block)
      assert_receive {:blocked, _}

      assert :ok = Tartarus.stop_host(h)
      for {ref, pid} <- Enum.zip(refs, pids), do: assert_receive({:DOWN, ^ref, _, ^pid, _}, 5_000)
    end

    test "a kill ends an idle agent that traps exits before Tartarus.kill/1 returns" do
      h = host!()
      {:ok, id} = Tartarus.create_agent(h, Blocker, %{test: self(), trap: true})
      pid = pid_of(id)
      assert :ok = Tartarus.kill(id)
      refute Process.alive?(pid)
    end
  end

  defp collect_logged(acc) do
    receive do
      {:logged, event} -> collect_logged([event | acc])
    after
      0 -> Enum.reverse(acc)
    end
  end
end
