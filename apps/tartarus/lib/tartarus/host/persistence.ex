defmodule Tartarus.Host.Persistence do
  @moduledoc false
  # A host's durable journal (host option :data_dir): one append-only file per host,
  # `host-<name>.journal`, of length-prefixed terms:
  #
  #   {:agent, id, env}                  agent arrived (or was created): its snapshot
  #   {:forget, id}                      agent stopped, or was killed
  #   {:in_doubt, mig, env, src, kind, copy}  this host prepared paused copy `copy` (destination)
  #   {:resolved, mig, copy}             that copy was committed or aborted
  #   {:acked, mig}                      the committed copy of mig runs: its decision record
  #                                      is no longer needed (source)
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
  # in-doubt copies, unacknowledged commits), not to the migrations that passed.
  #
  # Each write goes to the file with write(2) before the host sends the message that depends
  # on it (the destination records the in-doubt copy before answering `prepared`; the source
  # records its decision before sending `commit`; an arrival is recorded before the agent
  # runs), so it survives the node's OS process being killed. It is not fsync'ed: a power cut
  # before the OS writes its page cache back may lose the last records.

  @doc false
  # Opens (creating or compacting) the journal of host `name` in `dir`. Returns nil without a
  # directory, else `{journal, restored}` where restored is {agents, in_doubt, decided_migs}.
  def open(_name, nil), do: {nil, {[], [], []}}

  def open(name, dir) do
    File.mkdir_p!(dir)
    path = Path.join(dir, "host-#{safe(name)}.journal")
    {state, live} = compact(path)
    {:ok, pid} = Tartarus.Host.Persistence.Writer.start_link(path, live)
    {%{io: pid, path: path}, restored(state)}
  end

  def close(nil), do: :ok
  def close(%{io: pid}), do: GenServer.stop(pid)

  @doc false
  # Rewrites the journal at `path` with its live records. Returns {replayed state, bytes}.
  def compact(path) do
    state = replay(path)
    tmp = path <> ".tmp"
    bin = IO.iodata_to_binary(Enum.map(records(state), &frame/1))
    File.write!(tmp, bin)
    File.rename!(tmp, path)
    {state, byte_size(bin)}
  end

  @doc false
  # The journal's size on disk, in bytes (0 without one).
  def size(%{journal: nil}), do: 0
  def size(%{journal: %{path: path}}), do: File.stat!(path).size

  def checkpoint(%{journal: nil}, _env), do: :ok
  def checkpoint(%{journal: j}, env), do: append(j, {:agent, env.id, env})

  def forget(%{journal: nil}, _id), do: :ok
  def forget(%{journal: j}, id), do: append(j, {:forget, id})

  def in_doubt(%{journal: nil}, _mig, _env, _src, _kind, _copy), do: :ok

  def in_doubt(%{journal: j}, mig, env, src, kind, copy),
    do: append(j, {:in_doubt, mig, env, src, kind, copy})

  def resolved(%{journal: nil}, _mig, _copy), do: :ok
  def resolved(%{journal: j}, mig, copy), do: append(j, {:resolved, mig, copy})

  def acked(%{journal: nil}, _mig), do: :ok
  def acked(%{journal: j}, mig), do: append(j, {:acked, mig})

  def committed(%{journal: nil}, _mig, _id, _copy), do: :ok
  def committed(%{journal: j}, mig, id, copy), do: append(j, {:decision, mig, id, copy})

  # Returns once the record is written (write(2)), before the caller sends what depends on it.
  defp append(%{io: pid}, record),
    do: :ok = GenServer.call(pid, {:append, frame(record)}, :infinity)

  defp frame(record) do
    bin = :erlang.term_to_binary(record)
    <<byte_size(bin)::32, bin::binary>>
  end

  # -- replay ------------------------------------------------------------------------

  defp replay(path) do
    case File.read(path) do
      {:ok, bin} -> frames(bin, empty())
      {:error, :enoent} -> empty()
    end
  end

  @doc false
  # The replayed state of an empty journal (the fold of apply_record/2 over the records;
  # the protocol model folds the same way).
  def empty, do: %{agents: %{}, in_doubt: %{}, decisions: %{}}

  # A torn last frame (the node died mid-write) ends the replay.
  defp frames(<<size::32, bin::binary-size(size), rest::binary>>, state) do
    frames(rest, apply_record(:erlang.binary_to_term(bin), state))
  end

  defp frames(_torn_or_empty, state), do: state

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

  # A record of an earlier format: skipped.
  def apply_record(_other, s), do: s

  defp drop_agent(in_doubt, id, keep \\ nil),
    do: Map.reject(in_doubt, fn {{mig, _copy}, {env, _, _}} -> env.id == id and mig != keep end)

  defp records(s) do
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
  use GenServer
  require Tartarus.Events

  @compact_min 256 * 1024

  def start_link(path, live), do: GenServer.start_link(__MODULE__, {path, live})

  @impl true
  def init({path, live}) do
    {:ok, fd} = :file.open(path, [:append, :raw, :binary])
    {:ok, %{fd: fd, path: path, live: live, grown: 0}}
  end

  @impl true
  def handle_call(_msg, from, s) when not Tartarus.Events.is_from(from), do: {:noreply, s}

  def handle_call({:append, bin}, _from, s) when is_binary(bin) do
    :ok = :file.write(s.fd, bin)
    s = %{s | grown: s.grown + byte_size(bin)}
    {:reply, :ok, if(s.grown > max(@compact_min, 2 * s.live), do: compact(s), else: s)}
  end

  def handle_call(:compact, _from, s), do: {:reply, :ok, compact(s)}
  def handle_call(_other, _from, s), do: {:reply, {:error, :unexpected}, s}

  @impl true
  def handle_cast(_other, s), do: {:noreply, s}

  @impl true
  def handle_info(_other, s), do: {:noreply, s}

  @impl true
  def terminate(_reason, s), do: :file.close(s.fd)

  defp compact(s) do
    :ok = :file.close(s.fd)
    {_state, live} = Tartarus.Host.Persistence.compact(s.path)
    {:ok, fd} = :file.open(s.path, [:append, :raw, :binary])
    %{s | fd: fd, live: live, grown: 0}
  end
end
