defmodule Tartarus.Host.Persistence.JournalFile do
  @moduledoc false
  # The journal's file: frames `<<0xA7, size::32, crc32(size and term)::32, term>>`
  # (frame/1), each a record (Tartarus.Host.Persistence.Records) as an external term,
  # appended by the host's writer (Tartarus.Host.Persistence.Writer). read/1 replays the
  # frames that read whole, reports the bytes that did not and resynchronises on the next
  # frame; a journal of the first format (length-prefixed terms, no checksum) still reads.
  #
  # The journal is compacted (rewrite/2: the live records written to a temporary file,
  # renamed over the old one) on open and while the host runs (compact/1, from the writer),
  # so its size stays proportional to what is live (resident agents, in-doubt copies,
  # unacknowledged commits), not to the migrations that passed. A journal that does not read
  # whole is never compacted over: on open it is renamed aside (set_aside/2, `.damaged-<n>`,
  # kept for a person) before a fresh one takes the records that read; while the host runs it
  # is left as it is.

  alias Tartarus.Host.Persistence.Records

  # A frame: a marker byte, the payload's size, a CRC-32 of size and payload, the payload
  # (a record as an external term). The marker lets a reader find the next frame after a
  # damaged one; the checksum tells a frame from junk that looks like one.
  @marker 0xA7
  @head 9

  @doc false
  def frame(record) do
    bin = :erlang.term_to_binary(record)
    size = byte_size(bin)
    <<@marker, size::32, :erlang.crc32(<<size::32, bin::binary>>)::32, bin::binary>>
  end

  @doc false
  # Rewrites the journal at `path` with the live records of `state` (written to a temporary
  # file, then renamed over it). Returns {:ok, bytes} or {:error, reason}.
  def rewrite(path, state) do
    tmp = path <> ".tmp"
    bin = IO.iodata_to_binary(Enum.map(Records.records(state), &frame/1))

    with :ok <- File.write(tmp, bin),
         :ok <- File.rename(tmp, path) do
      {:ok, byte_size(bin)}
    else
      {:error, reason} ->
        _ = File.rm(tmp)
        {:error, reason}
    end
  end

  @doc false
  # Compacts the journal at `path` if it can be read whole: {:ok, bytes}; a journal with
  # unreadable parts is left as it is ({:error, {:damaged, damage}}): compaction never
  # replaces a file it could not fully read.
  def compact(path) do
    case read(path) do
      {:ok, state, %{ranges: []}} -> rewrite(path, state)
      {:ok, _state, damage} -> {:error, {:damaged, damage}}
      {:error, reason} -> {:error, reason}
    end
  end

  @doc false
  # A journal that could not be read whole (damage from read/1, nil if none) is kept,
  # renamed beside it (never deleted: a person may recover what the checksums refused),
  # before a fresh one replaces it: {:ok, where it went (nil if nowhere)} or {:error, reason}.
  def set_aside(_path, nil), do: {:ok, nil}

  def set_aside(path, _damage) do
    aside = free_name(path, 1)

    case File.rename(path, aside) do
      :ok -> {:ok, aside}
      {:error, reason} -> {:error, reason}
    end
  end

  defp free_name(path, n) do
    candidate = "#{path}.damaged-#{n}"
    if File.exists?(candidate), do: free_name(path, n + 1), else: candidate
  end

  # -- reading ---------------------------------------------------------------------------

  @doc false
  # Reads the journal at `path`: {:ok, state, %{ranges: ranges, records: n, bytes: size}}
  # where state is the fold of Records.apply_record/2 over every frame that reads whole
  # (checksum right, a record of a known shape) and ranges the [{offset, length}] of bytes
  # that did not, in order: a torn tail (the node died mid-write), a damaged frame in the
  # middle (the reader resynchronises on the next frame whose checksum holds), junk. A
  # missing file reads as empty. A journal of the first format (length-prefixed terms, no
  # checksum) is read as such when it reads whole that way (its next rewrite is in the new
  # one).
  @spec read(Path.t()) :: {:ok, map(), map()} | {:error, term()}
  def read(path) do
    case File.read(path) do
      {:ok, bin} ->
        {:ok, state, ranges, n} = parse(bin)
        {:ok, state, %{ranges: ranges, records: n, bytes: byte_size(bin)}}

      {:error, :enoent} ->
        {:ok, Records.empty(), %{ranges: [], records: 0, bytes: 0}}

      {:error, reason} ->
        {:error, reason}
    end
  end

  @doc false
  # The pure part of read/1: {:ok, state, unreadable ranges, records read}.
  @spec parse(binary()) :: {:ok, map(), [{non_neg_integer(), pos_integer()}], non_neg_integer()}
  def parse(<<0, _::binary>> = bin) do
    case legacy(bin) do
      {:ok, records, torn} ->
        {:ok, Enum.reduce(records, Records.empty(), &Records.apply_record/2), torn,
         length(records)}

      :error ->
        scan(bin, 0, Records.empty(), [], 0)
    end
  end

  def parse(bin), do: scan(bin, 0, Records.empty(), [], 0)

  defp scan(bin, off, state, ranges, n) when off >= byte_size(bin),
    do: {:ok, state, Enum.reverse(ranges), n}

  defp scan(bin, off, state, ranges, n) do
    case frame_at(bin, off) do
      {:ok, record, next} ->
        scan(bin, next, Records.apply_record(record, state), ranges, n + 1)

      :bad ->
        next = resync(bin, off + 1)
        scan(bin, next, state, [{off, next - off} | ranges], n)
    end
  end

  # The offset of the next frame that reads whole after `from`, or the end.
  defp resync(bin, from) do
    case :binary.match(bin, <<@marker>>, scope: {from, byte_size(bin) - from}) do
      {at, 1} -> if match?({:ok, _, _}, frame_at(bin, at)), do: at, else: resync(bin, at + 1)
      :nomatch -> byte_size(bin)
    end
  end

  defp frame_at(bin, off) do
    case bin do
      <<_::binary-size(off), @marker, size::32, crc::32, payload::binary-size(size), _::binary>> ->
        with true <- :erlang.crc32(<<size::32, payload::binary>>) == crc,
             {:ok, record} <- decode(payload),
             true <- Records.record?(record) do
          {:ok, record, off + @head + size}
        else
          _ -> :bad
        end

      _ ->
        :bad
    end
  end

  defp decode(payload) do
    {:ok, :erlang.binary_to_term(payload)}
  rescue
    ArgumentError -> :error
  end

  # The first format: a torn last frame ends it (and is reported); anything else that does
  # not read as a record means the file is not of that format. At least one record must
  # read (junk that begins with a zero byte is not a journal of the first format).
  defp legacy(bin), do: legacy(bin, 0, [])

  defp legacy(<<size::32, bin::binary-size(size), rest::binary>>, off, acc) do
    with {:ok, record} <- decode(bin), true <- Records.record?(record) do
      legacy(rest, off + 4 + size, [record | acc])
    else
      _ -> :error
    end
  end

  defp legacy(_rest, _off, []), do: :error
  defp legacy(<<>>, _off, acc), do: {:ok, Enum.reverse(acc), []}
  defp legacy(torn, off, acc), do: {:ok, Enum.reverse(acc), [{off, byte_size(torn)}]}
end
