defmodule TartarusTools.Bench.Churn do
  @moduledoc """
  What a host keeps of the migrations that passed through it: `mix tartarus.bench churn`.

  Two hosts in this VM, started with default options, and agents passing between them in
  batches: each batch creates `:agents` fresh agents (default 1,000) on the first host,
  each makes `:hops` hops (default 10) between the two hosts and then ends (returns its
  result), so the hosts see agents arrive, leave, die elsewhere, and new ones come. After
  10,000, 100,000 and 1,000,000 migrations (those not above `:migrations`, and
  `:migrations` itself), it measures, summed over both hosts:

    * every ETS table owned by the host's server process (today the ledger and the store),
    * the node's agent table (`Tartarus.AgentTable`), and
    * the host servers' own process memory (after a garbage collection),

  reported as `memory_bytes_at` (bytes, keyed by migration count), with the breakdown in
  `tables_at` (per count: bytes per part and entries of the hosts' tables by kind of key,
  the first element of a tuple key). Each measure is taken once the batches have settled:
  every agent of theirs ended and its end handled by its host's server (no agent process
  recorded in either ledger, both servers' queues empty), so what it finds is what the
  hosts keep, not the ends still under way; how long that took is `settle_ms_at` (with a
  journal the ends queue behind the journal's writer, so this is how far the hosts lag
  behind the agents), and a measure taken without settling within #{div(120_000, 1000)} s
  says so (`settle_ms_at` is then `"timeout"`). Then (unless `persist: false`) the same with hosts
  that journal to a data directory (`data_dir:`), whose journal files' size is added as
  `persist.journal_bytes_at` and included in `persist.memory_bytes_at`.

  Tables are found by owner, not by name, so the measure holds whatever tables the
  platform gives a host.
  """

  @checkpoints [10_000, 100_000, 1_000_000]

  @doc """
  Runs the churn benchmark. Options: `:migrations` (default 1,000,000), `:agents`
  (per batch, default 1,000), `:hops` (per agent, default 10), `:persist` (also the pass
  with a journal, default true), `:progress` (a 1-arity fun called with the migration
  count at each checkpoint).
  """
  @spec run(keyword()) :: map()
  def run(opts) do
    migrations = Keyword.get(opts, :migrations, 1_000_000)
    agents = Keyword.get(opts, :agents, 1_000)
    hops = Keyword.get(opts, :hops, 10)
    progress = Keyword.get(opts, :progress, fn _ -> :ok end)
    checkpoints = Enum.uniq(Enum.filter(@checkpoints, &(&1 < migrations)) ++ [migrations])
    failed_before = Tartarus.Events.totals().move_failed
    plain = pass(false, checkpoints, agents, hops, progress)
    failed_plain = Tartarus.Events.totals().move_failed - failed_before

    result = %{
      migrations: migrations,
      agents_per_batch: agents,
      hops_per_agent: hops,
      checkpoints: checkpoints,
      memory_bytes_at: plain.memory,
      tables_at: plain.tables,
      settle_ms_at: plain.settle,
      wall_ms: plain.wall_ms,
      migrations_per_s: plain.rate,
      # Moves that failed and were tried again (the benchmark's agent retries).
      moves_failed: failed_plain
    }

    if Keyword.get(opts, :persist, true) do
      failed_before = Tartarus.Events.totals().move_failed
      durable = pass(true, checkpoints, agents, hops, progress)

      Map.put(result, :persist, %{
        memory_bytes_at: durable.memory,
        journal_bytes_at: durable.journal,
        tables_at: durable.tables,
        settle_ms_at: durable.settle,
        wall_ms: durable.wall_ms,
        migrations_per_s: durable.rate,
        moves_failed: Tartarus.Events.totals().move_failed - failed_before
      })
    else
      result
    end
  end

  defp pass(persist, checkpoints, agents, hops, progress) do
    tag = System.unique_integer([:positive])
    dir = Path.join(System.tmp_dir!(), "tartarus_churn_#{tag}")
    host_opts = fn name -> if persist, do: [data_dir: Path.join(dir, "#{name}")], else: [] end
    {:ok, a} = Tartarus.start_host(:"churn_a#{tag}", host_opts.(:a))
    {:ok, b} = Tartarus.start_host(:"churn_b#{tag}", host_opts.(:b))
    module = TartarusTools.Bench.bouncer()
    blob = :crypto.strong_rand_bytes(1024)
    t0 = Tartarus.Clock.machine_time(:microsecond)

    try do
      :ok = Tartarus.connect(a, b)

      {rows, _} =
        Enum.map_reduce(checkpoints, 0, fn target, done ->
          churn(module, a, b, target - done, agents, hops, blob)
          progress.(target)
          settle_ms = settle([a, b])
          {{target, Map.put(measure([a, b], if(persist, do: dir)), :settle_ms, settle_ms)}, target}
        end)

      wall_us = max(Tartarus.Clock.machine_time(:microsecond) - t0, 1)

      %{
        memory: Map.new(rows, fn {n, m} -> {Integer.to_string(n), m.total + m.journal} end),
        journal: Map.new(rows, fn {n, m} -> {Integer.to_string(n), m.journal} end),
        tables:
          Map.new(rows, fn {n, m} ->
            {Integer.to_string(n), Map.drop(m, [:total, :settle_ms])}
          end),
        settle: Map.new(rows, fn {n, m} -> {Integer.to_string(n), m.settle_ms} end),
        wall_ms: div(wall_us, 1000),
        rate: round(List.last(checkpoints) * 1_000_000 / wall_us)
      }
    after
      Tartarus.stop_host(a)
      Tartarus.stop_host(b)
      File.rm_rf(dir)
    end
  end

  # `n` migrations in batches of `agents` agents making `hops` hops each (the last batch,
  # and its last agent, smaller).
  defp churn(_module, _a, _b, n, _agents, _hops, _blob) when n <= 0, do: :ok

  defp churn(module, a, b, n, agents, hops, blob) do
    batch = min(n, agents * hops)
    plan = List.duplicate(hops, div(batch, hops)) ++ if(rem(batch, hops) > 0, do: [rem(batch, hops)], else: [])
    TartarusTools.Bench.run_batch(module, a, b, plan, blob)
    churn(module, a, b, n - batch, agents, hops, blob)
  end

  @settle_max_ms 120_000

  # Waits (machine time: the apparatus, not the design) until no agent process is recorded
  # on either host and both servers' queues are empty: the ms it took, or "timeout".
  defp settle(hosts) do
    t0 = Tartarus.Clock.machine_time(:millisecond)
    settle(hosts, t0, t0)
  end

  defp settle(hosts, t0, now) do
    cond do
      Enum.all?(hosts, &settled?/1) ->
        now - t0

      now - t0 >= @settle_max_ms ->
        "timeout"

      true ->
        Tartarus.Clock.machine_sleep(50)
        settle(hosts, t0, Tartarus.Clock.machine_time(:millisecond))
    end
  end

  defp settled?(host) do
    {:ok, info} = Tartarus.Host.local(host)
    {:ok, pid} = Tartarus.Host.whereis(host)

    Tartarus.Ledger.procs(info) == [] and
      Process.info(pid, :message_queue_len) == {:message_queue_len, 0}
  end

  @doc false
  # Memory of hosts (on this node) and of the journal files under `dir`.
  def measure(hosts, dir) do
    words = :erlang.system_info(:wordsize)

    parts =
      for host <- hosts do
        {:ok, pid} = Tartarus.Host.whereis(host)
        {:ok, info} = Tartarus.Host.local(host)
        # The host's tables belong to its warden (they outlive a server that crashes).
        {name, _node} = host
        owners = Enum.reject([pid, GenServer.whereis(Tartarus.Host.via(:warden, name))], &is_nil/1)
        Enum.each(owners, &:erlang.garbage_collect/1)
        tables = Enum.filter(:ets.all(), &(:ets.info(&1, :owner) in owners))
        proc = owners |> Enum.map(&elem(Process.info(&1, :memory), 1)) |> Enum.sum()
        {Enum.sum(Enum.map(tables, &(:ets.info(&1, :memory) * words))), proc, entries(info, tables)}
      end

    tables = Enum.sum(Enum.map(parts, &elem(&1, 0)))
    procs = Enum.sum(Enum.map(parts, &elem(&1, 1)))
    agent_table = (:ets.info(Tartarus.AgentTable, :memory) || 0) * words
    kinds = Enum.reduce(parts, %{}, fn {_, _, e}, acc -> Map.merge(acc, e, fn _, x, y -> x + y end) end)
    journal = if dir, do: dir_bytes(dir), else: 0

    %{
      total: tables + procs + agent_table,
      host_tables: tables,
      host_processes: procs,
      agent_table: agent_table,
      journal: journal,
      entries: kinds
    }
  end

  # Records by key kind: the ledger's through Tartarus.Ledger.census/1, the host's other
  # tables (its store, its acknowledgements) by the first element of their keys.
  defp entries(info, tables) do
    ledger = for {kind, n} <- Tartarus.Ledger.census(info), into: %{}, do: {inspect(kind), n}

    tables
    |> Enum.reject(&Tartarus.Ledger.table?(info, &1))
    |> Enum.reduce(ledger, fn t, acc ->
      :ets.foldl(fn entry, acc -> Map.update(acc, kind(elem(entry, 0)), 1, &(&1 + 1)) end, acc, t)
    end)
  end

  defp kind(key) when is_tuple(key) and tuple_size(key) > 0, do: inspect(elem(key, 0))
  defp kind(key) when is_atom(key), do: inspect(key)
  defp kind(_key), do: "other"

  defp dir_bytes(dir) do
    Path.wildcard(Path.join(dir, "**/*"))
    |> Enum.map(fn p ->
      case File.stat(p) do
        {:ok, %{type: :regular, size: s}} -> s
        _ -> 0
      end
    end)
    |> Enum.sum()
  end
end
