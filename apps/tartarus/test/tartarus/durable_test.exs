defmodule Tartarus.DurableTest do
  # Durable acknowledged messages in one VM: `durable: true` and Tartarus.Agent.checkpoint/0
  # make a handled message's state the agent's snapshot (journaled with `data_dir:`), which
  # is what a restart restores. The SIGKILL case is test/durable_peer_test.exs.
  use Tartarus.HostCase, async: false

  defmodule Keeper do
    @moduledoc false
    # Keeps the messages it takes; `{:keep, m}` also asks for a checkpoint; `:crash` crashes.
    use Tartarus.Agent

    def init(s), do: {:stay, s}

    def handle_message(:crash, _from, _s), do: raise("boom")

    def handle_message(:state, from, s) do
      Tartarus.Agent.reply(from, s)
      {:stay, s}
    end

    def handle_message({:keep, m}, _from, s) do
      :ok = Tartarus.Agent.checkpoint()
      {:stay, [m | s]}
    end

    def handle_message(m, _from, s), do: {:stay, [m | s]}
  end

  defp journal_state(host, id) do
    {:ok, info} = Tartarus.Host.local(host)
    {:ok, s, %{ranges: []}} = Tartarus.Host.Persistence.JournalFile.read(info.journal.path)
    s.agents[id].state
  end

  defp dir do
    dir = Path.join(System.tmp_dir!(), "durable_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    dir
  end

  test "durable: each acknowledged post is in the journal before post/2 returns" do
    h = addr(host!(data_dir: dir(), durable: true))
    {:ok, id} = Tartarus.create_mobile_agent(h, Keeper, [])

    for i <- 1..5 do
      :ok = Tartarus.post({id, h}, i)
      assert journal_state(h, id) == Enum.to_list(i..1//-1)
    end
  end

  test "not durable: the journal keeps the state of the last arrival" do
    h = addr(host!(data_dir: dir()))
    {:ok, id} = Tartarus.create_mobile_agent(h, Keeper, [])
    for i <- 1..5, do: :ok = Tartarus.post({id, h}, i)
    assert {:ok, [5, 4, 3, 2, 1]} = Tartarus.request({id, h}, :state)
    assert journal_state(h, id) == []
  end

  test "Tartarus.Agent.checkpoint/0 journals the state the callback returns" do
    h = addr(host!(data_dir: dir()))
    {:ok, id} = Tartarus.create_mobile_agent(h, Keeper, [])
    :ok = Tartarus.post({id, h}, 1)
    :ok = Tartarus.post({id, h}, {:keep, 2})
    :ok = Tartarus.post({id, h}, 3)
    {:ok, _} = Tartarus.request({id, h}, :state)
    assert journal_state(h, id) == [2, 1]
  end

  test "durable without a data directory: a crash keeps acknowledged posts; the crashing one fails" do
    h = addr(host!(durable: true))
    {:ok, id} = Tartarus.create_mobile_agent(h, Keeper, [])
    for i <- 1..3, do: :ok = Tartarus.post({id, h}, i)
    # The message that crashed it is answered with an error, not taken again.
    assert {:error, :agent_crashed} = Tartarus.post({id, h}, :crash)
    assert {:ok, [3, 2, 1]} = Tartarus.request({id, h}, :state)
    assert Tartarus.status(h).counts.crashes == 1
  end

  test "an agent journaled by an earlier version (no :visit_order) is restored and travels on" do
    dir = Path.join(System.tmp_dir!(), "durable_old_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    File.mkdir_p!(dir)
    name = unique_name("old")
    id = Tartarus.Envelope.new_id()

    old =
      %Tartarus.Envelope{
        id: id,
        module: Tartarus.Examples.Echo,
        rng: Tartarus.Envelope.seed_rng(1),
        visits: %{{:gone, node()} => 3}
      }
      |> Map.from_struct()
      |> Map.delete(:visit_order)
      |> Map.put(:__struct__, Tartarus.Envelope)

    bin = :erlang.term_to_binary({:agent, id, old})
    File.write!(Path.join(dir, "host-#{name}.journal"), <<byte_size(bin)::32, bin::binary>>)

    {:ok, _} = Tartarus.start_host(name, data_dir: dir)
    on_exit(fn -> Tartarus.stop_host(name) end)
    other = host!()
    :ok = Tartarus.connect(name, other)

    assert eventually(fn -> Enum.any?(Tartarus.agents(name), &(&1.id == id)) end, 5_000)
    # The destination checks the envelope (Tartarus.Wire): an old one would be refused.
    assert :ok = Tartarus.move({id, name}, other)
    assert [%{id: ^id}] = Tartarus.agents(other)
  end

  test "checkpoint/0 outside an agent's callbacks is an error" do
    assert_raise ArgumentError, fn -> Tartarus.Agent.checkpoint() end
  end
end
