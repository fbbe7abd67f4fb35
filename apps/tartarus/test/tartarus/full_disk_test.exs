defmodule Tartarus.FullDiskTest do
  # A host whose data directory fills up: a real 64 KiB tmpfs (tag :tmpfs: root and mount).
  # Writes that cannot be journaled are refused with {:error, {:journal, :enospc}}; the host
  # keeps serving its residents; when space returns it journals again by itself; what it
  # answered :ok for is restored after a restart, and the journal reads whole. Before, the
  # writer's {:error, :enospc} stopped the host's server: every resident unreachable, and
  # the host could not start again until space was freed.
  use Tartarus.HostCase, async: false

  alias Tartarus.TestSupport.Tags

  @moduletag :tmpfs

  setup do
    dir = Path.join(System.tmp_dir!(), "full_disk_#{System.unique_integer([:positive])}")
    File.mkdir_p!(dir)
    :ok = Tags.mount_tmpfs(dir, "64k")

    on_exit(fn ->
      Tags.unmount(dir)
      File.rm_rf!(dir)
    end)

    %{dir: dir}
  end

  # Creates agents until one is refused: {ids created, the refusal}.
  defp fill(h, acc \\ []) do
    case Tartarus.create_agent(h, Tartarus.Test.Probe, %{count: 0, pad: :binary.copy("x", 512)}) do
      {:ok, id} when length(acc) < 10_000 -> fill(h, [id | acc])
      other -> {Enum.reverse(acc), other}
    end
  end

  test "creates refused with {:journal, :enospc}; residents served; recovers when space returns",
       %{dir: dir} do
    name = unique_name()
    {:ok, _} = Tartarus.start_host(name, data_dir: dir)
    on_exit(fn -> Tartarus.stop_host(name) end)
    {ids, refusal} = fill(name)
    assert refusal == {:error, {:journal, :enospc}}
    assert length(ids) > 10

    # Still serving: every resident listed and answering, the refusal in its status.
    assert Enum.sort(Enum.map(Tartarus.agents(name), & &1.id)) == Enum.sort(ids)
    assert Enum.all?(ids, &match?({:ok, %{count: 0}}, Tartarus.request({&1, addr(name)}, :state)))
    journal = Tartarus.status(name, [:journal]).journal
    assert journal.last_error == :enospc and journal.refused_writes >= 1

    # A move in is refused (the host could not journal the copy); the agent stays home.
    other = host!()
    :ok = Tartarus.connect(other, name)
    {:ok, mover} = Tartarus.create_agent(other, Tartarus.Test.Probe, %{count: 0})
    assert {:error, {:journal, :enospc}} = Tartarus.move({mover, addr(other)}, name)
    assert [%{id: ^mover}] = Tartarus.agents(other)

    # Space returns: the next create is journaled, with nobody restarting anything.
    :ok = Tags.resize_tmpfs(dir, "1m")
    assert {:ok, late} = Tartarus.create_agent(name, Tartarus.Test.Probe, %{count: 0})
    assert Tartarus.status(name, [:journal]).journal.last_error == nil

    # Everything answered :ok is restored, from a journal that reads whole.
    :ok = Tartarus.stop_host(name)
    {:ok, _} = Tartarus.start_host(name, data_dir: dir)
    assert Enum.sort(Enum.map(Tartarus.agents(name), & &1.id)) == Enum.sort([late | ids])
    assert Tartarus.status(name, [:journal]).journal.damaged == nil
  end

  test "durable: a post whose state cannot be journaled is refused, not acknowledged", %{dir: dir} do
    name = unique_name()
    {:ok, _} = Tartarus.start_host(name, data_dir: dir, durable: true)
    on_exit(fn -> Tartarus.stop_host(name) end)
    pad = :binary.copy("x", 2_048)
    {:ok, id} = Tartarus.create_agent(name, Tartarus.Test.Probe, %{count: 0, pad: pad})
    {_ids, {:error, {:journal, :enospc}}} = fill(name)

    # Each post journals the agent's new state (over 2 KiB): posts until one is refused.
    oks = Enum.take_while(1..1_000, fn _ -> Tartarus.post({id, addr(name)}, :inc) == :ok end)
    assert length(oks) < 1_000
    assert {:error, {:journal, :enospc}} = Tartarus.post({id, addr(name)}, :inc)
    # The agent goes on from the state before the refused messages: only the acknowledged
    # ones count, and a read is served.
    n = length(oks)
    assert {:ok, %{count: ^n}} = Tartarus.request({id, addr(name)}, :state)

    :ok = Tags.resize_tmpfs(dir, "1m")
    assert :ok = Tartarus.post({id, addr(name)}, :inc)
    m = n + 1
    assert {:ok, %{count: ^m}} = Tartarus.request({id, addr(name)}, :state)
  end

  test "a read-only file system: start_host answers one error naming the directory", %{dir: dir} do
    {_, 0} = System.cmd("mount", ["-o", "remount,ro", dir], stderr_to_stdout: true)
    name = unique_name()
    data = Path.join(dir, "data")
    assert {:error, {:journal, ^data, :erofs}} = Tartarus.start_host(name, data_dir: data)
    assert Tartarus.Host.local(name) == {:error, {:unknown_host, name}}
  end
end
