defmodule Tartarus.Host.Persistence.Writer do
  @moduledoc false
  # The one process that writes a host's journal (Tartarus.Host.Persistence starts it when
  # it opens the journal, and stops it): appends in the order they come, each answered once
  # written (write(2)), and compaction between two appends (nothing is appended while it
  # runs) once the file has grown by more than twice its live size (at least @compact_min
  # bytes), so its size stays proportional to what is live.
  #
  # A write that fails (a full disk: :enospc, a read-only or vanished file system) is
  # answered {:error, {:journal, reason}} and leaves nothing in the file: the bytes a
  # partial write left are cut off (the file is truncated back to where the write began).
  # The writer keeps serving: the next write is tried anew, so the journal recovers by
  # itself when space returns. While the last write failed, health/1 answers the error
  # (read from an atomic the writer sets), so a host refuses new work that needs the journal
  # instead of taking it undurably (Tartarus.Host.Persistence.healthy/1).
  #
  # A compaction that cannot read the file whole
  # (Tartarus.Host.Persistence.JournalFile.compact/1) leaves it as it is.
  use GenServer
  require Tartarus.Events

  @compact_min 256 * 1024

  # Write errors told apart by health/1 (any other reads as :io_error).
  @failures [:enospc, :erofs, :eacces, :edquot, :eio, :enoent, :io_error]

  @doc false
  # Starts the writer of the journal at `path` (`live`: its size in bytes after the
  # compaction of opening; `health`: a one-word atomics array it sets, read by health/1).
  def start_link(path, live, health),
    do: GenServer.start_link(__MODULE__, {path, live, health})

  @doc false
  # Appends `bin` (a frame) and returns once it is written, before the caller sends what
  # depends on it: :ok or {:error, {:journal, reason}} (nothing of it is then in the file).
  def append(pid, bin) do
    GenServer.call(pid, {:append, bin}, :infinity)
  catch
    :exit, _ -> {:error, {:journal, :writer_down}}
  end

  @doc false
  # The writer's counts: %{bytes, refused_writes, last_error} (:writer_down when it does not
  # answer).
  def status(pid) do
    GenServer.call(pid, :status, 5_000)
  catch
    :exit, _ -> %{bytes: nil, refused_writes: nil, last_error: :writer_down}
  end

  @doc false
  # :ok, or the error of the journal's last write as the health word `health` holds it.
  def health(health) do
    case :atomics.get(health, 1) do
      0 -> :ok
      code -> {:error, {:journal, Enum.at(@failures, code - 1, :io_error)}}
    end
  end

  # The code of a write error in the journal's health word (0: the last write succeeded).
  defp failure_code(nil), do: 0

  defp failure_code(reason),
    do: (Enum.find_index(@failures, &(&1 == reason)) || length(@failures)) + 1

  @impl true
  def init({path, live, health}) do
    case open(path) do
      {:ok, fd, size} ->
        {:ok,
         %{
           fd: fd,
           path: path,
           live: live,
           grown: 0,
           size: size,
           refused: 0,
           last_error: nil,
           health: health
         }}

      {:error, reason} ->
        {:stop, reason}
    end
  end

  defp open(path) do
    with {:ok, fd} <- :file.open(path, [:read, :write, :raw, :binary]),
         {:ok, size} <- :file.position(fd, :eof) do
      {:ok, fd, size}
    end
  end

  @impl true
  def handle_call(_msg, from, s) when not Tartarus.Events.is_from(from), do: {:noreply, s}

  def handle_call({:append, bin}, _from, s) when is_binary(bin) do
    case :file.write(s.fd, bin) do
      :ok ->
        s = failing(%{s | grown: s.grown + byte_size(bin), size: s.size + byte_size(bin)}, nil)
        {:reply, :ok, if(s.grown > max(@compact_min, 2 * s.live), do: compact(s), else: s)}

      {:error, reason} ->
        # Nothing of it stays: a torn frame here would be taken for damage by the next reader.
        _ = :file.position(s.fd, s.size)
        _ = :file.truncate(s.fd)
        s = failing(%{s | refused: s.refused + 1}, reason)
        {:reply, {:error, {:journal, reason}}, s}
    end
  end

  def handle_call(:compact, _from, s), do: {:reply, :ok, compact(s)}

  def handle_call(:status, _from, s),
    do: {:reply, %{bytes: s.size, refused_writes: s.refused, last_error: s.last_error}, s}

  def handle_call(_other, _from, s), do: {:reply, {:error, :unexpected}, s}

  @impl true
  def handle_cast(_other, s), do: {:noreply, s}

  @impl true
  def handle_info(_other, s), do: {:noreply, s}

  @impl true
  def terminate(_reason, s), do: :file.close(s.fd)

  defp failing(%{last_error: same} = s, same), do: s

  defp failing(s, reason) do
    :atomics.put(s.health, 1, failure_code(reason))
    %{s | last_error: reason}
  end

  # Rewritten with its live records, if it reads whole (else left as it is, and tried again
  # after as much growth again).
  defp compact(s) do
    :ok = :file.close(s.fd)

    s =
      case Tartarus.Host.Persistence.JournalFile.compact(s.path) do
        {:ok, live} -> %{s | live: live}
        {:error, _} -> s
      end

    case open(s.path) do
      {:ok, fd, size} -> %{s | fd: fd, size: size, grown: 0}
      {:error, reason} -> exit({:journal, s.path, reason})
    end
  end
end
