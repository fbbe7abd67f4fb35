defmodule Tartarus.AgentBoundsTest do
  # What an agent may not do to its host (issue 32, item 5): start with something that is
  # not an action, leave processes behind, grow without bound.
  use Tartarus.HostCase, async: false

  defmodule Garbage do
    @moduledoc false
    use Tartarus.Agent
    def init(what), do: what
  end

  defmodule Parent do
    @moduledoc false
    # Starts a child that traps exits (so a link alone would not end it) and reports it.
    use Tartarus.Agent

    def init(test) do
      child =
        Tartarus.Agent.spawn_link(fn ->
          Process.flag(:trap_exit, true)
          receive(do: (:never -> :ok))
        end)

      send(test, {:child, child})
      {:stay, test}
    end

    def handle_message(:stop, _from, s), do: {:stop, :done, s}
    def handle_message(:crash, _from, _s), do: raise("boom")
    def handle_message({:go, dest}, _from, s), do: {:move, dest, s}
  end

  defmodule Hog do
    @moduledoc false
    # Grows its heap until something stops it.
    use Tartarus.Agent
    def init(test), do: {:stay, test}

    def handle_message(:grow, _from, test) do
      send(test, {:growing, self()})
      grow([])
    end

    # 200 fresh words a step: the heap limit comes in milliseconds, long before the callback
    # budget even on a loaded machine.
    defp grow(acc), do: grow([:lists.seq(1, 100) | acc])
  end

  test "an init/1 that returns something other than an action fails the create" do
    h = host!()

    for bad <- [:garbage, {:stay}, {:move, :a}, %{stay: 1}, nil] do
      assert {:error, {:init_failed, {:bad_action, ^bad}}} =
               Tartarus.create_mobile_agent(h, Garbage, bad)
    end

    assert Tartarus.agents(h) == []
  end

  test "a child started with Tartarus.Agent.spawn_link/1 ends with its agent, however it ends" do
    h = host!(max_restarts: 0)
    other = host!()

    ends = [
      fn id -> :ok = Tartarus.kill({id, h}) end,
      fn id -> :ok = Tartarus.post({id, h}, :stop) end,
      fn id -> :ok = Tartarus.post({id, h}, :crash) end,
      fn id -> :ok = Tartarus.move({id, h}, other) end
    ]

    for finish <- ends do
      {:ok, id} = Tartarus.create_mobile_agent(h, Parent, self())
      assert_receive {:child, child}, 2_000
      ref = Process.monitor(child)
      finish.(id)
      assert_receive {:DOWN, ^ref, :process, ^child, :killed}, 2_000
    end
  end

  test "by default an agent's heap is bounded: one that grows without end is killed" do
    h = host!(max_restarts: 0)
    {:ok, id} = Tartarus.create_mobile_agent(h, Hog, self(), owner: self())
    Tartarus.cast({id, h}, :grow)
    assert_receive {:growing, pid}, 2_000
    ref = Process.monitor(pid)
    assert_receive {:DOWN, ^ref, :process, ^pid, :killed}, 30_000
    assert_receive {:tartarus_removed, ^id, _}, 5_000
  end
end
