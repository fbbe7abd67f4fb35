defmodule Tartarus.Migration.BoundedRecordsTest do
  # Records of migrations do not grow with the migrations that pass: aborts store nothing,
  # acknowledged commits are freed (a move's pointer only marked), the journal is compacted
  # while the host runs.
  use Tartarus.HostCase, async: false

  alias Tartarus.Examples.Echo

  alias Tartarus.Ledger

  defp local(host) do
    {:ok, h} = Tartarus.Host.local(host)
    h
  end

  defp decisions(host), do: Ledger.decisions(local(host))
  defp handoffs(host), do: Ledger.handoffs(local(host))

  defp unacked_pointers(host),
    do: for({_, _, {_mig, _copy}} = p <- Ledger.pointers(local(host)), do: p)

  # Acknowledgements leave in batches: until both hosts' outboxes are empty and each server
  # has handled what the other sent before (a call to each, in turn, after the flush).
  defp settle(hosts) do
    assert eventually(fn -> Enum.all?(hosts, &(:ets.info(local(&1).acks, :size) == 0)) end)
    for _ <- 1..2, h <- hosts, do: Tartarus.Host.call(h, :paused)
  end

  test "moves and clones leave no decision behind once their copies run" do
    [a, b] = [host!(), host!()]
    {:ok, id} = Tartarus.create_mobile_agent(a, Echo, :s)

    for _ <- 1..20 do
      :ok = Tartarus.move({id, a}, b)
      :ok = Tartarus.move({id, b}, a)
    end

    for _ <- 1..5, do: {:ok, _clone} = Tartarus.clone({id, a}, b)
    # Moves refused at the destination: aborted migrations.
    tiny = host!(admission: [max_message_bytes: 1])

    for _ <- 1..3,
        do: assert({:error, {:bad_message, {:too_large, _, 1}}} = Tartarus.move({id, a}, tiny))

    assert eventually(fn -> decisions(a) == [] and decisions(b) == [] end)
    assert eventually(fn -> unacked_pointers(a) == [] and unacked_pointers(b) == [] end)
    assert handoffs(a) == [] and handoffs(b) == []
    assert length(Tartarus.agents(b)) == 5
  end

  test "the journal stays bounded while the host runs, and a restart restores the agent once" do
    dir = Path.join(System.tmp_dir!(), "bounded_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    [na, nb] = [unique_name(), unique_name()]
    {:ok, a} = Tartarus.start_host(na, data_dir: dir)
    {:ok, b} = Tartarus.start_host(nb, data_dir: dir)
    {:ok, id} = Tartarus.create_mobile_agent(a, Echo, String.duplicate("x", 1_000))

    for _ <- 1..200 do
      :ok = Tartarus.move({id, a}, b)
      :ok = Tartarus.move({id, b}, a)
    end

    settle([na, nb])
    size = fn name -> File.stat!(Path.join(dir, "host-#{name}.journal")).size end
    # 400 arrivals of a 1 KB agent wrote far more than this; compaction keeps what is live.
    assert size.(na) < 320 * 1024 and size.(nb) < 320 * 1024

    :ok = Tartarus.stop_host(a)
    :ok = Tartarus.stop_host(b)
    {:ok, ^a} = Tartarus.start_host(na, data_dir: dir)
    {:ok, ^b} = Tartarus.start_host(nb, data_dir: dir)
    assert size.(na) < 8 * 1024 and size.(nb) < 8 * 1024
    assert eventually(fn -> length(Tartarus.agents(a)) == 1 end)
    assert Tartarus.agents(b) == []
    assert {:ok, state} = Tartarus.request({id, a}, :state)
    assert byte_size(state) == 1_000
    :ok = Tartarus.stop_host(a)
    :ok = Tartarus.stop_host(b)
  end
end

defmodule Tartarus.Migration.CloneRestartTest do
  # Regression of a bug the protocol model found (seed 22): a clone's commit lived only in
  # the source's ledger, so a clone whose commit message was lost was told aborted by its
  # restarted source. It is journaled now.
  use Tartarus.HostCase, async: false

  alias Tartarus.Fault

  test "a committed clone runs although its source host died before sending the commit" do
    dir = Path.join(System.tmp_dir!(), "clone_restart_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    name = unique_name()
    {:ok, a} = Tartarus.start_host(name, data_dir: dir, migration_timeout: 300)
    # The clone first asks after 1 s: by then its source has restarted.
    b = host!(migration_timeout: 1_000)
    {:ok, id} = Tartarus.create_mobile_agent(a, Tartarus.Examples.Echo, :original)

    Fault.install(:committing, {:once, {:pause, self()}})
    on_exit(fn -> Fault.clear(:committing) end)
    _cloner = Task.async(fn -> Tartarus.clone({id, a}, b) end)
    assert_receive {:fault_paused, :committing, _s_pid, _copy_pid}, 2_000

    # The source host dies between its (journaled) decision and the commit message.
    [{sup, _}] = Registry.lookup(Tartarus.HostRegistry, {:host_sup, name})
    Process.flag(:trap_exit, true)
    Process.exit(sup, :kill)
    assert eventually(fn -> Enum.all?(Tartarus.hosts(), &(&1 != a)) end, 2_000)
    {:ok, ^a} = Tartarus.start_host(name, data_dir: dir, migration_timeout: 300)

    # The clone asks the restarted source, learns of the commit and starts; the original is
    # restored at its source.
    assert eventually(fn -> length(Tartarus.agents(b)) == 1 end, 5_000)
    [%{id: clone}] = Tartarus.agents(b)
    assert {:ok, %{clone_of: ^id}} = Tartarus.agent_info({clone, b})
    assert eventually(fn -> match?([%{id: ^id}], Tartarus.agents(a)) end, 5_000)
    :ok = Tartarus.stop_host(a)
  end
end
