defmodule Tartarus.Host.Persistence do
  @moduledoc false
  # A host's durable journal (host option :data_dir): one append-only file per host,
  # `host-<name>.journal`, owned by the host's warden (Tartarus.Host.Warden). This module
  # opens it (open/2) and writes its records (checkpoint/2 ... committed/4); its parts:
  #
  #   Tartarus.Host.Persistence.Records      the records, what each means, and their replay
  #                                          (the fold that gives the state to restore)
  #   Tartarus.Host.Persistence.JournalFile  the file: frames, reading (setting aside what
  #                                          does not read, resynchronising on the next
  #                                          frame), rewriting and compacting
  #   Tartarus.Host.Persistence.Writer       the one process per host that appends to it and
  #                                          compacts it while the host runs
  #   Tartarus.Host.Persistence.ShippedCode  the code of journaled agents that is not on the
  #                                          node's code path, kept beside it
  #
  # Each write goes to the file with write(2) before the host sends the message that depends
  # on it (the destination records the in-doubt copy before answering `prepared`; the source
  # records its decision before sending `commit`; an arrival is recorded before the agent
  # runs), so it survives the node's OS process being killed. It is not fsync'ed: a power cut
  # before the OS writes its page cache back may lose the last records.

  alias Tartarus.Host.Persistence.{JournalFile, Records, ShippedCode, Writer}

  @doc false
  # Opens (creating or compacting) the journal of host `name` in `dir`: {:ok, nil, restored}
  # without a directory, else {:ok, journal, restored} where restored is {agents, in_doubt,
  # decided_migs} (Records.restored/1) and journal.damage what could not be read (see
  # JournalFile.read/1 and set_aside/2), or {:error, {:journal, path, reason}} when the
  # directory cannot be made or written (read-only, missing parent, not a directory).
  # Opening compacts the journal, keeping the code records only of the modules a live agent
  # or in-doubt copy needs, and loads the code it kept before any agent is restored.
  def open(_name, nil), do: {:ok, nil, {[], [], []}}

  def open(name, dir) do
    path = Path.join(dir, "host-#{safe(name)}.journal")

    with :ok <- mkdir(dir),
         {:ok, state, damage} <- read_checked(path),
         {:ok, moved} <- JournalFile.set_aside(path, damage),
         kept = Records.needed_code(state),
         {:ok, live} <- JournalFile.rewrite(path, kept),
         :ok <- ShippedCode.drop_unused(path, kept.code),
         unloadable = ShippedCode.load(path, state.code),
         health = :atomics.new(1, []),
         {:ok, pid} <- Writer.start_link(path, live, health) do
      damage = if damage, do: Map.put(damage, :moved_to, moved)
      journal = %{io: pid, path: path, damage: damage, health: health, unloadable: unloadable}
      {:ok, journal, Records.restored(state)}
    else
      {:error, {:journal, _, _}} = error -> error
      {:error, reason} -> {:error, {:journal, path, reason}}
    end
  end

  defp mkdir(dir) do
    case File.mkdir_p(dir) do
      :ok -> :ok
      {:error, reason} -> {:error, {:journal, dir, reason}}
    end
  end

  defp read_checked(path) do
    case JournalFile.read(path) do
      {:ok, state, %{ranges: []}} -> {:ok, state, nil}
      {:ok, state, damage} -> {:ok, state, damage}
      {:error, reason} -> {:error, reason}
    end
  end

  defp safe(name), do: name |> to_string() |> String.replace(~r/[^A-Za-z0-9_.-]/, "_")

  @doc false
  # Stops the journal's writer (the warden, as the host stops).
  def close(nil), do: :ok
  def close(%{io: pid}), do: GenServer.stop(pid)

  @doc false
  # The journal's size on disk, in bytes (0 without one).
  def size(%{journal: nil}), do: 0
  def size(%{journal: %{path: path}}), do: File.stat!(path).size

  # -- the records (Records) --------------------------------------------------------------
  #
  # Each write answers :ok once written, or {:error, {:journal, reason}} (a full disk:
  # {:journal, :enospc}) when it could not be: nothing of it is then in the file. Without a
  # journal (host.journal nil) each answers :ok.

  @doc false
  # An agent arrived (or was created): its snapshot, after the code it needs.
  def checkpoint(%{journal: nil}, _env), do: :ok

  def checkpoint(%{journal: j} = host, env) do
    with :ok <- save_code(host, env), do: append(j, {:agent, env.id, env})
  end

  @doc false
  # An agent stopped, or was killed.
  def forget(%{journal: nil}, _id), do: :ok
  def forget(%{journal: j}, id), do: append(j, {:forget, id})

  @doc false
  # This host (the destination) prepared paused copy `copy` of migration `mig`, before it
  # answers `prepared`.
  def in_doubt(%{journal: nil}, _mig, _env, _src, _kind, _copy), do: :ok

  def in_doubt(%{journal: j} = host, mig, env, src, kind, copy) do
    with :ok <- save_code(host, env), do: append(j, {:in_doubt, mig, env, src, kind, copy})
  end

  @doc false
  # The in-doubt copy `copy` of `mig` was committed or aborted.
  def resolved(%{journal: nil}, _mig, _copy), do: :ok
  def resolved(%{journal: j}, mig, copy), do: append(j, {:resolved, mig, copy})

  @doc false
  # The committed copy of `mig` runs: the decision record is no longer needed (source).
  def acked(%{journal: nil}, _mig), do: :ok
  def acked(%{journal: j}, mig), do: append(j, {:acked, mig})

  @doc false
  # This host (the source) committed `mig` of agent `id` to `copy`, before it sends `commit`.
  def committed(%{journal: nil}, _mig, _id, _copy), do: :ok
  def committed(%{journal: j}, mig, id, copy), do: append(j, {:decision, mig, id, copy})

  # Keeps the code of env's modules that is not on the node's code path beside the journal
  # (ShippedCode): the binary, then its record, once per run of the host (the ledger
  # remembers it).
  defp save_code(host, env) do
    Enum.reduce_while(Tartarus.Envelope.modules(env), :ok, fn mod, :ok ->
      case save_module(host, mod) do
        :ok -> {:cont, :ok}
        error -> {:halt, error}
      end
    end)
  end

  defp save_module(%{journal: j} = host, mod) do
    with {:ok, md5} <- ShippedCode.shipped_md5(mod),
         false <- Tartarus.Ledger.code_saved?(host, mod, md5),
         :ok <- ShippedCode.keep(j.path, mod, md5),
         :ok <- append(j, {:code, mod, md5}) do
      Tartarus.Ledger.code_saved(host, mod, md5)
      :ok
    else
      true -> :ok
      # On the code path, not loaded (it cannot run here either) or no binary: nothing to keep.
      :none -> :ok
      {:error, _} = error -> error
    end
  end

  # Returns once the record is written (write(2)), before the caller sends what depends on it.
  defp append(%{io: pid}, record), do: Writer.append(pid, JournalFile.frame(record))

  # -- health and status -----------------------------------------------------------------

  @doc false
  # :ok, or the error of the journal's last write if it failed (nothing written since): a
  # host refuses new work that needs the journal meanwhile (Tartarus.Host.Arrivals).
  def healthy(%{journal: nil}), do: :ok
  def healthy(%{journal: %{health: health}}), do: Writer.health(health)

  @doc false
  # The journal's part of a host's status (Tartarus.status/2, key :journal): nil without
  # one.
  def status(%{journal: nil}), do: nil

  def status(%{journal: %{io: pid, path: path, damage: damage}}),
    do: Map.merge(Writer.status(pid), %{path: path, damaged: damage})

  # -- replay (Records), as a host replays its journal: the protocol model folds the same --

  @doc false
  defdelegate empty(), to: Records

  @doc false
  defdelegate apply_record(record, state), to: Records

  @doc false
  defdelegate restored(state), to: Records
end
