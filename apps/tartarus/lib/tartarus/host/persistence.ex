defmodule Tartarus.Host.Persistence do
  @moduledoc false
  # A host's durable checkpoints (host option :data_dir), in one DETS file per host.
  #
  # Records (seq is a per-host counter that orders writes, so a restore can tell which of two
  # records about the same agent is newer even if the host died between two writes):
  #
  #   {{:agent, id}, seq, env}                 resident agent, snapshot taken on arrival
  #   {{:in_doubt, mig}, seq, env, src, kind}  a paused copy this host prepared (destination)
  #   {{:decision, mig}, seq, id}              a migration of agent id this host committed (source)
  #   {:seq, n}
  #
  # Writes that matter for the guarantees happen before the message that depends on them:
  # the destination records the in-doubt copy before answering `prepared`; the source records
  # its commit decision before sending `commit`; an arrival is checkpointed before the agent
  # runs. DETS delays writes in its own cache (up to 3 s), so each of these writes is followed
  # by :dets.sync/1, which hands them to the OS: they survive the node's OS process being
  # killed (a power cut before the OS flushes its page cache is another matter).

  @doc false
  def open(_name, nil), do: nil

  def open(name, dir) do
    File.mkdir_p!(dir)
    file = Path.join(dir, "host-#{safe(name)}.dets") |> String.to_charlist()

    case :dets.open_file({:tartarus_host, name}, file: file, type: :set, repair: true) do
      {:ok, tab} ->
        :dets.insert_new(tab, {:seq, 0})
        tab

      {:error, reason} ->
        raise ArgumentError, "cannot open the data directory #{dir}: #{inspect(reason)}"
    end
  end

  def close(nil), do: :ok
  def close(tab), do: :dets.close(tab)

  def checkpoint(%{dets: nil}, _env), do: :ok
  def checkpoint(%{dets: tab}, env), do: durable(tab, {{:agent, env.id}, next(tab), env})

  def forget(%{dets: nil}, _id), do: :ok

  def forget(%{dets: tab}, id) do
    :dets.delete(tab, {:agent, id})
    :dets.sync(tab)
  end

  def in_doubt(%{dets: nil}, _mig, _env, _src, _kind), do: :ok

  def in_doubt(%{dets: tab}, mig, env, src, kind),
    do: durable(tab, {{:in_doubt, mig}, next(tab), env, src, kind})

  def resolved(%{dets: nil}, _mig), do: :ok
  def resolved(%{dets: tab}, mig), do: :dets.delete(tab, {:in_doubt, mig})

  def committed(%{dets: nil}, _mig, _id), do: :ok
  def committed(%{dets: tab}, mig, id), do: durable(tab, {{:decision, mig}, next(tab), id})

  def committed?(%{dets: nil}, _mig), do: false
  def committed?(%{dets: tab}, mig), do: :dets.member(tab, {:decision, mig})

  @doc false
  # What to restore: agents to restart and in-doubt copies to recreate, dropping records that
  # a newer record about the same agent supersedes.
  def restore(%{dets: nil}), do: {[], []}

  def restore(%{dets: tab}) do
    records = :dets.foldl(fn r, acc -> [r | acc] end, [], tab)

    decided =
      for {{:decision, _}, seq, id} <- records,
          reduce: %{},
          do: (acc -> Map.update(acc, id, seq, &max(&1, seq)))

    arrived = for {{:agent, id}, seq, _} <- records, into: %{}, do: {id, seq}

    agents = for {{:agent, id}, seq, env} <- records, seq > Map.get(decided, id, -1), do: env

    in_doubt =
      for {{:in_doubt, mig}, seq, env, src, kind} <- records,
          seq > Map.get(arrived, env.id, -1),
          do: {mig, env, src, kind}

    # Superseded records are dropped from the file.
    for {{:agent, id}, seq, _} <- records,
        seq <= Map.get(decided, id, -1),
        do: :dets.delete(tab, {:agent, id})

    for {{:in_doubt, mig}, seq, env, _, _} <- records,
        seq <= Map.get(arrived, env.id, -1),
        do: :dets.delete(tab, {:in_doubt, mig})

    {agents, in_doubt}
  end

  defp durable(tab, record) do
    :ok = :dets.insert(tab, record)
    :dets.sync(tab)
  end

  defp next(tab), do: :dets.update_counter(tab, :seq, 1)

  defp safe(name), do: name |> to_string() |> String.replace(~r/[^A-Za-z0-9_.-]/, "_")
end
