defmodule Tartarus.Host.Persistence do
  @moduledoc false
  # A host's durable journal (host option :data_dir): one append-only file per host,
  # `host-<name>.journal`, owned by the host's warden (Tartarus.Host.Warden), of frames
  # `<<0xA7, size::32, crc32(size and term)::32, term>>` (frame/1; read/1 reads them, sets
  # aside what does not read and resynchronises on the next frame) holding the records:
  #
  #   {:agent, id, env}                  agent arrived (or was created): its snapshot
  #   {:forget, id}                      agent stopped, or was killed
  #   {:in_doubt, mig, env, src, kind, copy}  this host prepared paused copy `copy` (destination)
  #   {:resolved, mig, copy}             that copy was committed or aborted
  #   {:acked, mig}                      the committed copy of mig runs: its decision record
  #                                      is no longer needed (source)
  #   {:code, module, md5}               the binary of `module` a journaled agent needs is
  #                                      kept in code/<md5>.beam (see "shipped code" below)
  #
  # In-doubt copies are keyed by {mig, copy}: a second copy of one migration (a duplicated or
  # replayed prepare the host no longer remembered) must not replace the first's record.
  #   {:decision, mig, id, copy}         this host committed migration mig of agent id to the
  #                                      paused copy `copy` (source)
  #
  # Replaying the journal in order gives the state to restore; a `decision` or a later
  # `agent` record supersedes earlier records about the same agent, so a host that died
  # between two writes restores nothing twice. The journal is compacted (rewritten with the
  # live records and renamed over the old one) on open and while the host runs: its writer
  # (Tartarus.Host.Persistence.Writer, one process per host, owning the file) compacts it
  # between two writes once it has grown by more than twice its live size (at least
  # @compact_min bytes), so its size stays proportional to what is live (resident agents,
  # in-doubt copies, unacknowledged commits), not to the migrations that passed. A journal
  # that does not read whole is never compacted over: on open it is renamed aside
  # (`.damaged-<n>`, kept for a person) before a fresh one takes the records that read; while
  # the host runs it is left as it is.
  #
  # Each write goes to the file with write(2) before the host sends the message that depends
  # on it (the destination records the in-doubt copy before answering `prepared`; the source
  # records its decision before sending `commit`; an arrival is recorded before the agent
  # runs), so it survives the node's OS process being killed. It is not fsync'ed: a power cut
  # before the OS writes its page cache back may lose the last records.

  @doc false
  # Opens (creating or compacting) the journal of host `name` in `dir`: {:ok, nil, restored}
  # without a directory, else {:ok, journal, restored} where restored is {agents, in_doubt,
  # decided_migs} and journal.damage what could not be read (see read/1 and set_aside/2),
  # or {:error, {:journal, path, reason}} when the directory cannot be made or written
  # (read-only, missing parent, not a directory).
  def open(_name, nil), do: {:ok, nil, {[], [], []}}

  def open(name, dir) do
    path = Path.join(dir, "host-#{safe(name)}.journal")

    with :ok <- mkdir(dir),
         {:ok, state, damage} <- read_checked(path),
         {:ok, moved} <- set_aside(path, damage),
         {:ok, live} <- rewrite(path, state, true),
         unloadable = load_code(path, state),
         health = :atomics.new(1, []),
         {:ok, pid} <- Tartarus.Host.Persistence.Writer.start_link(path, live, health) do
      damage = if damage, do: Map.put(damage, :moved_to, moved)
      journal = %{io: pid, path: path, damage: damage, health: health, unloadable: unloadable}
      {:ok, journal, restored(state)}
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
    case read(path) do
      {:ok, state, %{ranges: []}} -> {:ok, state, nil}
      {:ok, state, damage} -> {:ok, state, damage}
      {:error, reason} -> {:error, reason}
    end
  end

  # A journal that could not be read whole is kept, renamed beside it (never deleted: a
  # person may recover what the checksums refused), before a fresh one replaces it.
  defp set_aside(_path, nil), do: {:ok, nil}

  defp set_aside(path, _damage) do
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

  def close(nil), do: :ok
  def close(%{io: pid}), do: GenServer.stop(pid)

  @doc false
  # Rewrites the journal at `path` with the live records of `state` (written to a temporary
  # file, then renamed over it). Returns {:ok, bytes} or {:error, reason}.
  def rewrite(path, state, gc_code \\ false) do
    state = if gc_code, do: needed_code(state), else: state
    tmp = path <> ".tmp"
    bin = IO.iodata_to_binary(Enum.map(records(state), &frame/1))

    with :ok <- File.write(tmp, bin),
         :ok <- File.rename(tmp, path) do
      if gc_code, do: drop_unused_code(path, state)
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
  # The journal's size on disk, in bytes (0 without one).
  def size(%{journal: nil}), do: 0
  def size(%{journal: %{path: path}}), do: File.stat!(path).size

  # Write errors told apart by Persistence.healthy/1 (any other reads as :io_error).
  @failures [:enospc, :erofs, :eacces, :edquot, :eio, :enoent, :io_error]

  # Each write answers :ok once written, or {:error, {:journal, reason}} (a full disk:
  # {:journal, :enospc}) when it could not be: nothing of it is then in the file.
  def checkpoint(%{journal: nil}, _env), do: :ok

  def checkpoint(%{journal: j} = host, env) do
    with :ok <- save_code(host, env), do: append(j, {:agent, env.id, env})
  end

  def forget(%{journal: nil}, _id), do: :ok
  def forget(%{journal: j}, id), do: append(j, {:forget, id})

  def in_doubt(%{journal: nil}, _mig, _env, _src, _kind, _copy), do: :ok

  def in_doubt(%{journal: j} = host, mig, env, src, kind, copy) do
    with :ok <- save_code(host, env), do: append(j, {:in_doubt, mig, env, src, kind, copy})
  end

  def resolved(%{journal: nil}, _mig, _copy), do: :ok
  def resolved(%{journal: j}, mig, copy), do: append(j, {:resolved, mig, copy})

  def acked(%{journal: nil}, _mig), do: :ok
  def acked(%{journal: j}, mig), do: append(j, {:acked, mig})

  def committed(%{journal: nil}, _mig, _id, _copy), do: :ok
  def committed(%{journal: j}, mig, id, copy), do: append(j, {:decision, mig, id, copy})

  # -- shipped code ----------------------------------------------------------------------
  #
  # The code of a journaled agent that is not on the node's code path (shipped from another
  # node, or compiled at run time) is kept beside the journal, content-addressed: the BEAM
  # binary in `code/<md5 in hex>.beam` (written once, to a temporary file renamed into
  # place), and a record {:code, module, md5} in the journal. Replaying keeps the last md5
  # of each module; the compaction of opening keeps the records of the modules a live agent
  # or in-doubt copy needs and deletes the files of the others (the last agent that needed
  # them is gone; compactions while the host runs keep every code record, so the ledger's
  # memory of what was saved stays true). Opening the journal loads each kept module whose md5 the node does not run
  # already (Tartarus.CodeCache.load/1 checks the binary's md5), before any agent is
  # restored. Each module is saved once per run of the host (a ledger entry remembers it).

  defp save_code(host, env) do
    Enum.reduce_while(Tartarus.Envelope.modules(env), :ok, fn mod, :ok ->
      case save_module(host, mod) do
        :ok -> {:cont, :ok}
        error -> {:halt, error}
      end
    end)
  end

  defp save_module(%{journal: j} = host, mod) do
    with false <- on_code_path?(mod),
         {:ok, md5} <- Tartarus.CodeCache.md5(mod),
         false <- Tartarus.Ledger.code_saved?(host, mod, md5),
         {:ok, bin} <- Tartarus.CodeCache.fetch_binary(mod, md5),
         :ok <- write_code(j, md5, bin),
         :ok <- append(j, {:code, mod, md5}) do
      Tartarus.Ledger.code_saved(host, mod, md5)
      :ok
    else
      true -> :ok
      # Not loaded (it cannot run here either) or no binary: nothing to keep.
      :error -> :ok
      {:error, {:no_object_code, _}} -> :ok
      {:error, _} = error -> error
    end
  end

  defp on_code_path?(mod) do
    case :code.which(mod) do
      path when is_list(path) -> String.ends_with?(List.to_string(path), ".beam")
      _ -> false
    end
  end

  defp code_path(journal_path, md5),
    do:
      Path.join([Path.dirname(journal_path), "code", Base.encode16(md5, case: :lower) <> ".beam"])

  defp write_code(%{path: path}, md5, bin) do
    file = code_path(path, md5)
    tmp = file <> ".tmp"

    with false <- File.exists?(file),
         :ok <- File.mkdir_p(Path.dirname(file)),
         :ok <- File.write(tmp, bin),
         :ok <- File.rename(tmp, file) do
      :ok
    else
      true ->
        :ok

      {:error, reason} ->
        _ = File.rm(tmp)
        {:error, {:journal, reason}}
    end
  end

  # Loads the modules the journal kept (state.code) that this node does not run in that
  # version: [{module, error}] for those that could not be loaded.
  defp load_code(path, state) do
    for {mod, md5} <- state.code,
        Tartarus.CodeCache.md5(mod) != {:ok, md5},
        result = load_module(path, mod, md5),
        result != :ok,
        do: {mod, result}
  end

  defp load_module(path, mod, md5) do
    with {:ok, bin} <- File.read(code_path(path, md5)) do
      Tartarus.CodeCache.load([{mod, md5, bin}])
    end
  end

  # Deletes the kept binaries no live record needs any more (compaction).
  defp drop_unused_code(path, state) do
    dir = Path.join(Path.dirname(path), "code")

    keep =
      MapSet.new(state.code, fn {_mod, md5} -> Base.encode16(md5, case: :lower) <> ".beam" end)

    case File.ls(dir) do
      {:ok, files} ->
        for f <- files,
            String.ends_with?(f, ".beam"),
            f not in keep,
            do: File.rm(Path.join(dir, f))

        :ok

      {:error, _} ->
        :ok
    end
  end

  @doc false
  # :ok, or the error of the journal's last write if it failed (nothing written since): a
  # host refuses new work that needs the journal meanwhile (Tartarus.Host.Arrivals).
  def healthy(%{journal: nil}), do: :ok

  def healthy(%{journal: %{health: health}}) do
    case :atomics.get(health, 1) do
      0 -> :ok
      code -> {:error, {:journal, Enum.at(@failures, code - 1, :io_error)}}
    end
  end

  @doc false
  # The code of a write error in the journal's health word (0: the last write succeeded).
  def failure_code(nil), do: 0

  def failure_code(reason),
    do: (Enum.find_index(@failures, &(&1 == reason)) || length(@failures)) + 1

  @doc false
  # The journal's part of a host's status (Tartarus.status/2, key :journal): nil without
  # one.
  def status(%{journal: nil}), do: nil

  def status(%{journal: %{io: pid, path: path, damage: damage}}) do
    counts =
      try do
        GenServer.call(pid, :status, 5_000)
      catch
        :exit, _ -> %{bytes: nil, refused_writes: nil, last_error: :writer_down}
      end

    Map.merge(counts, %{path: path, damaged: damage})
  end

  # Returns once the record is written (write(2)), before the caller sends what depends on it.
  defp append(%{io: pid}, record) do
    GenServer.call(pid, {:append, frame(record)}, :infinity)
  catch
    :exit, _ -> {:error, {:journal, :writer_down}}
  end

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

  # -- replay ------------------------------------------------------------------------

  @doc false
  # Reads the journal at `path`: {:ok, state, %{ranges: ranges, records: n, bytes: size}}
  # where state is the fold of apply_record/2 over every frame that reads whole (checksum
  # right, a record of a known shape) and ranges the [{offset, length}] of bytes that did
  # not, in order: a torn tail (the node died mid-write), a damaged frame in the middle (the
  # reader resynchronises on the next frame whose checksum holds), junk. A missing file
  # reads as empty. A journal of the first format (length-prefixed terms, no checksum)
  # is read as such when it reads whole that way (its next rewrite is in the new one).
  @spec read(Path.t()) :: {:ok, map(), map()} | {:error, term()}
  def read(path) do
    case File.read(path) do
      {:ok, bin} ->
        {:ok, state, ranges, n} = parse(bin)
        {:ok, state, %{ranges: ranges, records: n, bytes: byte_size(bin)}}

      {:error, :enoent} ->
        {:ok, empty(), %{ranges: [], records: 0, bytes: 0}}

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
        {:ok, Enum.reduce(records, empty(), &apply_record/2), torn, length(records)}

      :error ->
        scan(bin, 0, empty(), [], 0)
    end
  end

  def parse(bin), do: scan(bin, 0, empty(), [], 0)

  defp scan(bin, off, state, ranges, n) when off >= byte_size(bin),
    do: {:ok, state, Enum.reverse(ranges), n}

  defp scan(bin, off, state, ranges, n) do
    case frame_at(bin, off) do
      {:ok, record, next} ->
        scan(bin, next, apply_record(record, state), ranges, n + 1)

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
             true <- record?(record) do
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
    with {:ok, record} <- decode(bin), true <- record?(record) do
      legacy(rest, off + 4 + size, [record | acc])
    else
      _ -> :error
    end
  end

  defp legacy(_rest, _off, []), do: :error
  defp legacy(<<>>, _off, acc), do: {:ok, Enum.reverse(acc), []}
  defp legacy(torn, off, acc), do: {:ok, Enum.reverse(acc), [{off, byte_size(torn)}]}

  @doc false
  # Whether `term` is a journal record of a shape apply_record/2 knows.
  def record?({:agent, id, %{id: id}}) when is_binary(id), do: true
  def record?({:forget, id}) when is_binary(id), do: true

  def record?({:in_doubt, _mig, %{id: id}, _src, kind, _copy})
      when is_binary(id) and is_atom(kind),
      do: true

  def record?({:resolved, _mig, _copy}), do: true
  def record?({:acked, _mig}), do: true
  def record?({:decision, _mig, id, _copy}) when is_binary(id), do: true
  def record?({:code, mod, md5}) when is_atom(mod) and is_binary(md5), do: true
  def record?(_), do: false

  @doc false
  # The replayed state of an empty journal (the fold of apply_record/2 over the records;
  # the protocol model folds the same way).
  def empty, do: %{agents: %{}, in_doubt: %{}, decisions: %{}, code: %{}}

  @doc false
  def apply_record({:agent, id, env}, s),
    do: %{s | agents: Map.put(s.agents, id, env), in_doubt: drop_agent(s.in_doubt, id)}

  def apply_record({:forget, id}, s), do: %{s | agents: Map.delete(s.agents, id)}

  def apply_record({:in_doubt, mig, env, src, kind, copy}, s),
    do: %{s | in_doubt: Map.put(s.in_doubt, {mig, copy}, {env, src, kind})}

  def apply_record({:resolved, mig, copy}, s),
    do: %{s | in_doubt: Map.delete(s.in_doubt, {mig, copy})}

  def apply_record({:decision, mig, id, copy}, s) do
    # A move to this same host has its in-doubt copy here too: that one stays (it asks, finds
    # the decision and starts).
    %{
      s
      | agents: Map.delete(s.agents, id),
        in_doubt: drop_agent(s.in_doubt, id, mig),
        decisions: Map.put(s.decisions, mig, {id, copy})
    }
  end

  def apply_record({:acked, mig}, s), do: %{s | decisions: Map.delete(s.decisions, mig)}

  def apply_record({:code, mod, md5}, s),
    do: %{s | code: Map.put(Map.get(s, :code, %{}), mod, md5)}

  # A record of an unknown shape (read/1 sets such frames aside): skipped.
  def apply_record(_other, s), do: s

  defp drop_agent(in_doubt, id, keep \\ nil),
    do: Map.reject(in_doubt, fn {{mig, _copy}, {env, _, _}} -> env.id == id and mig != keep end)

  # The code records a live agent or in-doubt copy needs (the others are dropped).
  defp needed_code(s) do
    envs = Map.values(s.agents) ++ Enum.map(Map.values(s.in_doubt), &elem(&1, 0))
    needed = MapSet.new(Enum.flat_map(envs, &modules_of/1))
    %{s | code: Map.filter(Map.get(s, :code, %{}), fn {mod, _} -> mod in needed end)}
  end

  defp modules_of(env) do
    Tartarus.Envelope.modules(Tartarus.Envelope.upgrade(env))
  rescue
    _ -> []
  end

  defp records(s) do
    Enum.map(Map.get(s, :code, %{}), fn {mod, md5} -> {:code, mod, md5} end) ++
      Enum.map(s.decisions, fn {mig, {id, copy}} -> {:decision, mig, id, copy} end) ++
      Enum.map(s.in_doubt, fn {{mig, copy}, {env, src, kind}} ->
        {:in_doubt, mig, env, src, kind, copy}
      end) ++
      Enum.map(s.agents, fn {id, env} -> {:agent, id, env} end)
  end

  @doc false
  # {agents, in_doubt as [{mig, env, src, kind, copy}], decisions as [{mig, copy}]}.
  def restored(s) do
    # Envelopes an earlier version journaled take this version's shape.
    up = &Tartarus.Envelope.upgrade/1

    {Enum.map(Map.values(s.agents), up),
     Enum.map(s.in_doubt, fn {{mig, copy}, {env, src, kind}} ->
       {mig, up.(env), src, kind, copy}
     end), Enum.map(s.decisions, fn {mig, {_id, copy}} -> {mig, copy} end)}
  end

  defp safe(name), do: name |> to_string() |> String.replace(~r/[^A-Za-z0-9_.-]/, "_")
end

defmodule Tartarus.Host.Persistence.Writer do
  @moduledoc false
  # The one process that writes a host's journal: appends in the order they come, each
  # answered once written, and compaction between two appends (nothing is appended while it
  # runs), when the file has grown by more than twice its live size.
  #
  # A write that fails (a full disk: :enospc, a read-only or vanished file system) is
  # answered {:error, {:journal, reason}} and leaves nothing in the file: the bytes a
  # partial write left are cut off (the file is truncated back to where the write began).
  # The writer keeps serving: the next write is tried anew, so the journal recovers by
  # itself when space returns. While the last write failed, Persistence.healthy/1 answers
  # the error (read from an atomic the writer sets), so a host refuses new work that needs
  # the journal instead of taking it undurably.
  #
  # A compaction that cannot read the file whole (Persistence.compact/1) leaves it as it is.
  use GenServer
  require Tartarus.Events

  @compact_min 256 * 1024

  def start_link(path, live, health),
    do: GenServer.start_link(__MODULE__, {path, live, health})

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
    :atomics.put(s.health, 1, Tartarus.Host.Persistence.failure_code(reason))
    %{s | last_error: reason}
  end

  # Rewritten with its live records, if it reads whole (else left as it is, and tried again
  # after as much growth again).
  defp compact(s) do
    :ok = :file.close(s.fd)

    s =
      case Tartarus.Host.Persistence.compact(s.path) do
        {:ok, live} -> %{s | live: live}
        {:error, _} -> s
      end

    case open(s.path) do
      {:ok, fd, size} -> %{s | fd: fd, size: size, grown: 0}
      {:error, reason} -> exit({:journal, s.path, reason})
    end
  end
end
