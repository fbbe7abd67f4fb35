defmodule Tartarus.CallbacksTest do
  # Agent callbacks never block a host: init/1 and the other callbacks run in the agent's
  # own process under the host's :callback_timeout budget, and a kill never waits in the host
  # server, whatever the agent traps. Assertions are on the order of events (an answer that
  # arrives while an agent is provably still stuck), never on how long something took.
  use Tartarus.HostCase, async: false

  defmodule Picky do
    @moduledoc false
    # Answers :ping; has no clause for anything else (its handler crashes).
    use Tartarus.Agent

    @impl true
    def init(s), do: {:stay, s}

    @impl true
    def handle_message(:ping, from, s) do
      Tartarus.Agent.reply(from, :pong)
      {:stay, s}
    end
  end

  defmodule Stuck do
    @moduledoc false
    # An agent that gets stuck where its arguments say: in init/1 (`wedge: :init`), in
    # handle_arrival/2 (`wedge: :arrival`), in handle_message/3 on `:block` (until it
    # receives `:release`, or for ever with `:block_forever`). With `trap: true` it traps
    # exits. It reports each step to `test`.
    use Tartarus.Agent

    @impl true
    def init(%{test: test} = s) do
      if s[:trap], do: Process.flag(:trap_exit, true)

      case s do
        %{wedge: :init} ->
          send(test, {:in_init, self()})
          Process.sleep(:infinity)

        %{move_to: dest} ->
          {:move, dest, Map.delete(s, :move_to)}

        _ ->
          {:stay, s}
      end
    end

    @impl true
    def handle_arrival(_ctx, %{wedge: :arrival, test: test}) do
      send(test, {:arrived, self()})
      Process.sleep(:infinity)
    end

    def handle_arrival(_ctx, s), do: {:stay, s}

    @impl true
    def handle_message(:block, _from, %{test: test} = s) do
      send(test, {:blocked, self()})

      receive do
        :release -> {:stay, s}
      end
    end

    def handle_message(:block_forever, _from, %{test: test}) do
      send(test, {:blocked, self()})
      Process.sleep(:infinity)
    end

    def handle_message({:sleep, ms}, _from, s) do
      Process.sleep(ms)
      {:stay, Map.put(s, :slept, ms)}
    end

    def handle_message(_msg, _from, s), do: {:stay, s}

    @impl true
    def handle_info(msg, %{test: test} = s) do
      send(test, {:info, self(), msg})
      {:stay, s}
    end
  end

  defp host_pid(name) do
    {:ok, pid} = Tartarus.Host.whereis(name)
    pid
  end

  describe "init/1" do
    test "a wedged init/1 leaves its host working: create, kill, start_host, stop_host answer" do
      h = host!(callback_timeout: :infinity)
      me = self()
      # It traps exits, too: stop_host must not wait for it.
      creating =
        Task.async(fn ->
          Tartarus.create_agent(h, Stuck, %{test: me, wedge: :init, trap: true})
        end)

      assert_receive {:in_init, wedged}, 5_000

      # All of this happens while init/1 is provably still running (no budget ends it).
      {:ok, other} = Tartarus.create_agent(h, Stuck, %{test: me})
      assert {:ok, %{host: {^h, _}}} = Tartarus.agent_info(other)
      assert :ok = Tartarus.kill(other)
      assert {:error, :not_found} = Tartarus.agent_info(other)

      h2 = unique_name()
      assert {:ok, _} = Tartarus.start_host(h2)
      assert :ok = Tartarus.stop_host(h2)
      assert Process.alive?(wedged)
      assert Task.yield(creating, 0) == nil

      assert :ok = Tartarus.stop_host(h)
      refute Process.alive?(wedged)
      # Its creator hears back (the host is gone).
      assert {:error, _} = Task.await(creating)
    end

    test "an init/1 over its budget is stopped and its creator told so" do
      h = host!(callback_timeout: 200)

      for trap <- [false, true] do
        assert {:error, {:callback_timeout, :init, 200}} =
                 Tartarus.create_agent(h, Stuck, %{test: self(), wedge: :init, trap: trap})

        assert_received {:in_init, wedged}
        # The host answers once the process is down.
        refute Process.alive?(wedged)
      end

      # Nothing left of it; the host works on.
      assert Tartarus.agents(h) == []
      {:ok, id} = Tartarus.create_agent(h, Stuck, %{test: self()})
      assert [%{id: ^id}] = Tartarus.agents(h)
    end

    test "an init/1 that crashes still answers {:init_failed, reason}" do
      h = host!(callback_timeout: 1_000)

      assert {:error, {:init_failed, {:error, :function_clause, _}}} =
               Tartarus.create_agent(h, Stuck, %{})

      assert Tartarus.agents(h) == []
    end
  end

  describe "other callbacks" do
    test "a wedged handle_arrival/2 after a move: the agent is removed, its host works on" do
      [a, b] = line!(2, callback_timeout: 300)
      me = self()

      {:ok, id} =
        Tartarus.create_agent(a, Stuck, %{test: me, wedge: :arrival, move_to: b}, owner: me)

      assert_receive {:arrived, stuck}, 5_000

      # Host b answers while the arrival is stuck (it may or may not be over its budget yet:
      # either way b works).
      {:ok, other} = Tartarus.create_agent(b, Stuck, %{test: me})
      assert {:ok, {^b, _}} = Tartarus.whereis({other, b})

      assert_receive {:tartarus_removed, ^id, {:callback_timeout, :handle_arrival, 300}}, 5_000
      refute Process.alive?(stuck)
      assert Enum.map(Tartarus.agents(b), & &1.id) == [other]
      assert {:error, :not_found} = Tartarus.whereis({id, b})
      # Not restarted: it would hang again.
      refute_received {:arrived, _}
    end

    test "a wedged handle_message/3: the agent is removed, its requester and owner told" do
      h = host!(callback_timeout: 200)
      {:ok, id} = Tartarus.create_agent(h, Stuck, %{test: self()}, owner: self())
      # Its requester is told.
      assert Tartarus.request(id, :block_forever, 60_000) ==
               {:error, {:callback_timeout, :handle_message, 200}}

      assert_receive {:blocked, stuck}
      assert_receive {:tartarus_removed, ^id, {:callback_timeout, :handle_message, 200}}, 5_000
      refute Process.alive?(stuck)
      assert Tartarus.agents(h) == []
    end

    test "a callback that returns after its budget ran out counts as an overrun" do
      h = host!(callback_timeout: 100)
      {:ok, id} = Tartarus.create_agent(h, Stuck, %{test: self()}, owner: self())
      {:ok, %{pid: pid}} = Tartarus.agent_info(id)
      mref = Process.monitor(pid)
      # The watchdog (the host server) is held back: the callback returns late, and the
      # agent stops itself, its result ignored.
      :ok = :sys.suspend(host_pid(h))

      assert Tartarus.request(id, {:sleep, 300}, 60_000) ==
               {:error, {:callback_timeout, :handle_message, 100}}

      assert_receive {:DOWN, ^mref, :process, ^pid, {:callback_timeout, :handle_message, 100}},
                     5_000

      :ok = :sys.resume(host_pid(h))
      assert_receive {:tartarus_removed, ^id, {:callback_timeout, :handle_message, 100}}, 5_000
      assert Tartarus.agents(h) == []
    end

    test "a forged overrun timer stops nothing" do
      h = host!(callback_timeout: 60_000)
      {:ok, id} = Tartarus.create_agent(h, Stuck, %{test: self()})
      {:ok, %{pid: pid}} = Tartarus.agent_info(id)
      send(host_pid(h), {:timeout, make_ref(), {:"$tartarus_overrun", pid}})

      # Also while it is inside a callback (its real timer is armed, but not this one).
      assert :ok = Tartarus.post(id, :block)
      assert_receive {:blocked, ^pid}
      send(host_pid(h), {:timeout, make_ref(), {:"$tartarus_overrun", pid}})
      # The host handled both (a call is answered after the messages sent before it).
      assert [%{id: ^id}] = Tartarus.agents(h)
      send(pid, :release)
      assert {:ok, %{pid: ^pid}} = Tartarus.agent_info(id)
    end
  end

  describe "kill" do
    test "an agent that traps exits, stuck in a callback: the host answers while the kill waits" do
      h = host!(callback_timeout: 60_000)
      me = self()
      {:ok, id} = Tartarus.create_agent(h, Stuck, %{test: me, trap: true})
      assert :ok = Tartarus.post(id, :block)
      assert_receive {:blocked, stuck}

      killing = Task.async(fn -> Tartarus.kill(id) end)
      hpid = host_pid(h)
      # The host has sent its shutdown signal (the agent traps it: a message it cannot take
      # while its callback runs, so it stays in its mailbox).
      eventually(fn -> {:EXIT, hpid, :shutdown} in elem(Process.info(stuck, :messages), 1) end)

      # The kill is under way (the agent is alive, stuck until we release it) and the host
      # answers other calls, a second kill included.
      {:ok, other} = Tartarus.create_agent(h, Stuck, %{test: me})
      assert :ok = Tartarus.kill(other)
      assert [%{id: ^id}] = Tartarus.agents(h)
      assert Process.alive?(stuck)
      assert Task.yield(killing, 0) == nil

      # Released, the agent returns {:stay, _}: it stops all the same, its code never sees
      # the signal.
      send(stuck, :release)
      assert Task.await(killing) == :ok
      refute Process.alive?(stuck)
      refute_received {:info, ^stuck, _}
      assert Tartarus.agents(h) == []
      assert {:error, :not_found} = Tartarus.agent_info(id)
    end

    test "an idle agent that traps exits is killed" do
      h = host!()
      {:ok, id} = Tartarus.create_agent(h, Stuck, %{test: self(), trap: true})
      {:ok, %{pid: pid}} = Tartarus.agent_info(id)
      assert :ok = Tartarus.kill(id)
      refute Process.alive?(pid)
      refute_received {:info, ^pid, _}
    end

    test "an agent that traps exits and never returns is killed at the end of its budget" do
      h = host!(callback_timeout: 1_000)
      {:ok, id} = Tartarus.create_agent(h, Stuck, %{test: self(), trap: true}, owner: self())
      assert :ok = Tartarus.post(id, :block_forever)
      assert_receive {:blocked, stuck}
      assert :ok = Tartarus.kill(id)
      refute Process.alive?(stuck)
      assert Tartarus.agents(h) == []
      # Killed, not removed for its overrun (whichever came first, the kill answered).
      refute_received {:tartarus_removed, ^id, _}
    end

    test "a forged exit message does not stop an agent that traps exits" do
      h = host!()
      {:ok, id} = Tartarus.create_agent(h, Stuck, %{test: self(), trap: true})
      {:ok, %{pid: pid}} = Tartarus.agent_info(id)
      hpid = host_pid(h)
      send(pid, {:EXIT, hpid, :shutdown})
      assert_receive {:info, ^pid, {:EXIT, ^hpid, :shutdown}}
      assert {:ok, %{pid: ^pid}} = Tartarus.agent_info(id)
    end
  end

  test "a request whose handler crashes is answered with the crash at once, not a time-out" do
    h = host!()
    {:ok, id} = Tartarus.create_agent(h, Picky, :kept)
    t0 = System.monotonic_time(:millisecond)
    # Picky has a clause for :ping only: its handle_message/3 raises on anything else.
    assert {:error, {:agent_crashed, reason}} =
             Tartarus.request({id, h}, {:no, :such, :clause}, 60_000)

    assert inspect(reason) =~ ~r/FunctionClauseError|function_clause/
    # Well before the minute it was given (the crash, not a time-out, answered).
    assert System.monotonic_time(:millisecond) - t0 < 30_000
    # The host restarts it from its snapshot (asynchronously: until then it is not found);
    # then it answers.
    assert Enum.any?(1..100, fn _ ->
             Tartarus.request({id, h}, :ping, 5_000) == {:ok, :pong} or
               (Process.sleep(20) && false)
           end)
  end

  test "an agent's crash is logged once, by its host, naming the agent's id and module" do
    h = host!()
    {:ok, id} = Tartarus.create_agent(h, Picky, :kept)
    :ok = :logger.add_handler(:crash_spy, Tartarus.Test.LogSpy, %{config: self()})
    on_exit(fn -> :logger.remove_handler(:crash_spy) end)

    assert {:error, {:agent_crashed, _}} = Tartarus.request({id, h}, :unknown_msg, 60_000)
    # Once it answers again, the host has handled its crash (logged, then restarted it).
    assert Enum.any?(1..100, fn _ ->
             Tartarus.request({id, h}, :ping, 5_000) == {:ok, :pong} or
               (Process.sleep(20) && false)
           end)

    :ok = :logger.remove_handler(:crash_spy)
    events = collect_logged([])
    assert [line] = events |> Enum.map(&text(&1.msg)) |> Enum.filter(&(&1 =~ id))
    assert line =~ "(Tartarus.CallbacksTest.Picky) crashed on host #{inspect({h, node()})}"
    assert line =~ "FunctionClauseError"
    assert line =~ "restarted from its arrival snapshot (1 of"
    # gen_statem's own report of the crash does not get past the primary filters.
    refute Enum.any?(events, &match?(%{msg: {:report, %{label: {:gen_statem, _}}}}, &1))
  end

  defp collect_logged(acc) do
    receive do
      {:logged, event} -> collect_logged([event | acc])
    after
      0 -> Enum.reverse(acc)
    end
  end

  defp text({:string, s}), do: IO.chardata_to_string(s)
  defp text({:report, report}), do: inspect(report)
  defp text({format, args}), do: IO.chardata_to_string(:io_lib.format(format, args))

  test "callback_timeout is a host option: a positive integer or :infinity" do
    assert {:error, message} = Tartarus.start_host(unique_name(), callback_timeout: 0)
    assert message =~ "for key :callback_timeout: expected a positive integer or :infinity"
  end
end
