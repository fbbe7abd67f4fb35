defmodule Tartarus.JournalIntegrityTest do
  # A host's journal (data_dir:) damaged while the host was down: each record checksummed,
  # the intact ones restored, what could not be read moved aside (the original file kept
  # whole beside the new one, never deleted) and reported in an event, a log line and the
  # host's status. Before, one junk byte made the host restore nothing and rewrite the
  # journal to 0 bytes; a flipped length prefix dropped every record after it; a flipped
  # term byte or a record that is no envelope kept the host from starting.
  use Tartarus.HostCase, async: false

  alias Tartarus.Host.Persistence.JournalFile

  @n 100

  setup do
    dir = Path.join(System.tmp_dir!(), "journal_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    name = unique_name()
    {:ok, _} = Tartarus.start_host(name, data_dir: dir)
    ids = for i <- 1..@n, do: agent!(name, %{count: i})
    :ok = Tartarus.stop_host(name)
    path = Path.join(dir, "host-#{name}.journal")
    %{dir: dir, name: name, ids: ids, path: path}
  end

  # The frames of a journal as {offset, size of the whole frame}.
  defp frames(bin, off \\ 0)

  defp frames(<<0xA7, size::32, _crc::32, _::binary-size(size), rest::binary>>, off),
    do: [{off, 9 + size} | frames(rest, off + 9 + size)]

  defp frames(<<>>, _off), do: []

  defp restart(ctx, damaged) do
    File.write!(ctx.path, damaged)
    Tartarus.Events.subscribe()
    {:ok, _} = Tartarus.start_host(ctx.name, data_dir: ctx.dir)
    on_exit(fn -> Tartarus.stop_host(ctx.name) end)
    restored = Enum.map(Tartarus.agents(ctx.name), & &1.id)
    journal = Tartarus.status(ctx.name, [:journal]).journal
    {restored, journal}
  end

  # What every damage must come with: the event, the status, the original kept whole.
  defp assert_reported(journal, damaged, restored) do
    assert %{ranges: [_ | _] = ranges, moved_to: aside, records: records} = journal.damaged
    assert records == length(restored)
    assert File.read!(aside) == damaged
    bytes = Enum.reduce(ranges, 0, fn {_, n}, acc -> acc + n end)

    assert_receive {:tartarus_event,
                    %{type: :journal_damaged, ranges: ^ranges, unreadable_bytes: ^bytes}}

    # The new journal reads whole: a restart now restores the same and reports nothing.
    assert {:ok, _, %{ranges: []}} = JournalFile.read(journal.path)
    ranges
  end

  defp intact?(restored, ids), do: Enum.all?(restored, &(&1 in ids))

  test "an undamaged journal restores every agent and reports nothing", ctx do
    {restored, journal} = restart(ctx, File.read!(ctx.path))
    assert Enum.sort(restored) == Enum.sort(ctx.ids)
    assert journal.damaged == nil
    refute_receive {:tartarus_event, %{type: :journal_damaged}}, 50
  end

  test "a torn tail: the last record is cut and reported, the rest restored", ctx do
    bin = File.read!(ctx.path)
    damaged = binary_part(bin, 0, byte_size(bin) - 10)
    {restored, journal} = restart(ctx, damaged)
    assert length(restored) == @n - 1 and intact?(restored, ctx.ids)
    {last_off, last_size} = List.last(frames(bin))
    assert [{^last_off, n}] = assert_reported(journal, damaged, restored)
    assert n == last_size - 10
  end

  test "a truncated journal: the records before the cut restored, the cut frame reported", ctx do
    bin = File.read!(ctx.path)
    {off, _} = Enum.at(frames(bin), 40)
    damaged = binary_part(bin, 0, off + 20)
    {restored, journal} = restart(ctx, damaged)
    assert length(restored) == 40 and intact?(restored, ctx.ids)
    assert [{^off, 20}] = assert_reported(journal, damaged, restored)
  end

  test "a flipped length prefix: that record is set aside, every record after it restored", ctx do
    bin = File.read!(ctx.path)
    {off, _} = Enum.at(frames(bin), 50)
    <<pre::binary-size(off + 1), b, post::binary>> = bin
    damaged = <<pre::binary, Bitwise.bxor(b, 0x40), post::binary>>
    {restored, journal} = restart(ctx, damaged)
    assert length(restored) == @n - 1 and intact?(restored, ctx.ids)
    assert [{^off, _}] = assert_reported(journal, damaged, restored)
  end

  test "a flipped byte in a term's header: that record is set aside, the others restored", ctx do
    bin = File.read!(ctx.path)
    {off, size} = Enum.at(frames(bin), 30)
    # The external term format's version byte (131), first of the payload.
    <<pre::binary-size(off + 9), 131, post::binary>> = bin
    damaged = <<pre::binary, 132, post::binary>>
    {restored, journal} = restart(ctx, damaged)
    assert length(restored) == @n - 1 and intact?(restored, ctx.ids)
    assert [{^off, ^size}] = assert_reported(journal, damaged, restored)
  end

  test "a file of junk: the host starts with nothing restored, the junk kept and reported", ctx do
    damaged = :crypto.strong_rand_bytes(20_000)
    {restored, journal} = restart(ctx, damaged)
    assert restored == []
    assert [{0, 20_000}] = assert_reported(journal, damaged, restored)
  end

  test "one junk byte prepended: every record restored, the byte reported", ctx do
    damaged = <<0x55>> <> File.read!(ctx.path)
    {restored, journal} = restart(ctx, damaged)
    assert Enum.sort(restored) == Enum.sort(ctx.ids)
    assert [{0, 1}] = assert_reported(journal, damaged, restored)
  end

  test "a well-framed record that is not an envelope: set aside, the others restored", ctx do
    bin = File.read!(ctx.path)
    {off, _} = Enum.at(frames(bin), 60)
    bad = JournalFile.frame({:agent, "not-an-envelope", :junk})
    damaged = binary_part(bin, 0, off) <> bad <> binary_part(bin, off, byte_size(bin) - off)
    {restored, journal} = restart(ctx, damaged)
    assert Enum.sort(restored) == Enum.sort(ctx.ids)
    assert [{^off, n}] = assert_reported(journal, damaged, restored)
    assert n == byte_size(bad)
  end

  test "a read-only data directory: start_host answers one error naming it" do
    dir = Path.join(System.tmp_dir!(), "ro_#{System.unique_integer([:positive])}")
    File.mkdir_p!(dir)
    on_exit(fn -> File.rm_rf!(dir) end)
    File.chmod!(dir, 0o500)
    on_exit(fn -> File.chmod(dir, 0o700) end)
    name = unique_name()

    # Root ignores permissions: there the test makes the directory's place a file instead.
    dir =
      if match?({:ok, _}, File.open(Path.join(dir, "probe"), [:write])) do
        File.chmod!(dir, 0o700)
        file = Path.join(dir, "a-file")
        File.write!(file, "")
        Path.join(file, "data")
      else
        dir
      end

    assert {:error, {:journal, path, reason}} = Tartarus.start_host(name, data_dir: dir)
    assert reason in [:eacces, :erofs, :enotdir]
    assert String.starts_with?(path, dir) or String.starts_with?(dir, path)
    assert Tartarus.Host.local(name) == {:error, {:unknown_host, name}}
  end

  test "compaction leaves a journal it cannot read whole as it is" do
    dir = Path.join(System.tmp_dir!(), "compact_#{System.unique_integer([:positive])}")
    File.mkdir_p!(dir)
    on_exit(fn -> File.rm_rf!(dir) end)
    path = Path.join(dir, "j")
    good = JournalFile.frame({:forget, "a"})
    damaged = good <> "junk" <> good
    File.write!(path, damaged)
    assert {:error, {:damaged, %{ranges: [{_, 4}]}}} = JournalFile.compact(path)
    assert File.read!(path) == damaged
  end
end
