defmodule TartarusDashboard.Health do
  @moduledoc """
  The BEAM's health on this node, sampled over time for the dashboard: one process per node
  (registered as `#{inspect(__MODULE__)}`) takes a sample every `:every_ms` (1 s) and keeps
  the last `:keep` (300: five minutes) in a ring.

  A sample (`t` is the node's clock in ms):

    * `memory`: `total`, `processes`, `ets`, `binary` (bytes, `:erlang.memory/0`);
    * `processes`: the process count; `run_queue`: the total of the run queues and
      `run_queues`, each scheduler's (`:erlang.statistics(:run_queue_lengths)`);
    * `sched_util`: the schedulers' utilisation since the previous sample, 0..1
      (`:scheduler_wall_time`, which the sampler turns on);
    * `mailbox_max` and `mailboxes`: the longest agent mailboxes (`[%{id, name, host, len}]`,
      the 5 longest) among at most `:max_agents` agents read per sample (the next ones are
      read at the next sample, so every agent is seen in turn on a large node);
    * `hop_p50_us`, `hop_p90_us`, `hop_p99_us`: arrivals' hop times on this node's hosts (at
      most `:max_hosts` hosts read per sample, in turn);
    * `arrivals`, `refused`: arrivals and refused arrivals since the previous sample (the
      node's counters, `Tartarus.Events.totals/0`);
    * `hosts`: per host, for at most `:max_hosts` hosts of this node (in turn):
      `%{residents, arrivals, refused, mailbox_max, hop_p50_us, hop_p99_us}`;
    * `cost_us`: what taking this sample took (wall clock: on a busy node it includes the
      time other processes ran meanwhile), and `cost_reductions`, the work it did in
      reductions (the sampler's own, which load does not inflate).

  Sampling is bounded: a sample reads at most `:max_agents` agents' mailbox lengths and
  `:max_hosts` hosts, whatever the node's size (its `cost_us` is in every sample); the list
  of the node's hosts it takes them from is read again every 30 samples (on a node of 10,000
  hosts listing them costs more than the rest of a sample).
  """

  use GenServer

  alias Tartarus.Clock

  @schema [
    every_ms: [type: :pos_integer, default: 1_000, doc: "ms between samples"],
    keep: [type: :pos_integer, default: 300, doc: "samples kept (the ring's size)"],
    max_agents: [type: :pos_integer, default: 2_000, doc: "agents' mailboxes read per sample"],
    max_hosts: [type: :pos_integer, default: 64, doc: "hosts read per sample"]
  ]

  @doc "The options' schema."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Starts this node's sampler if it is not running (not linked: it lives as long as the
  node). Returns its pid. Options as in the moduledoc; ignored if it already runs.
  """
  @spec ensure_started(keyword()) :: pid()
  def ensure_started(opts \\ []) do
    case Process.whereis(__MODULE__) do
      nil ->
        opts = Tartarus.Options.validate!(opts, @schema, inspect(__MODULE__))

        case GenServer.start(__MODULE__, opts, name: __MODULE__) do
          {:ok, pid} -> pid
          {:error, {:already_started, pid}} -> pid
        end

      pid ->
        pid
    end
  end

  @doc "Stops this node's sampler (if it runs)."
  @spec stop() :: :ok
  def stop do
    case Process.whereis(__MODULE__) do
      nil -> :ok
      pid -> GenServer.stop(pid)
    end
  catch
    :exit, _ -> :ok
  end

  @doc """
  The last `points` samples of this node, oldest first (starts the sampler if needed, and
  then takes a first sample at once).
  """
  @spec series(pos_integer()) :: [map()]
  def series(points \\ 300) do
    GenServer.call(ensure_started(), {:series, points}, 10_000)
  end

  @doc "The last sample of this node (nil before the first)."
  @spec latest() :: map() | nil
  def latest, do: List.last(series(1))

  @doc false
  # The longest mailboxes: the `n` longest of `entries` ([%{len: ...}]), longest first.
  def longest(entries, n), do: entries |> Enum.sort_by(&(-&1.len)) |> Enum.take(n)

  @doc false
  # Utilisation between two `:scheduler_wall_time` readings: 0..1, or nil.
  def utilisation(prev, now) when is_list(prev) and is_list(now) do
    p = Map.new(prev, fn {i, a, t} -> {i, {a, t}} end)

    {active, total} =
      Enum.reduce(now, {0, 0}, fn {i, a, t}, {sa, st} ->
        case p do
          %{^i => {a0, t0}} -> {sa + a - a0, st + t - t0}
          _ -> {sa, st}
        end
      end)

    if total > 0, do: Float.round(active / total, 3), else: nil
  end

  def utilisation(_, _), do: nil

  # -- the process ------------------------------------------------------------------------

  @impl true
  def init(opts) do
    :erlang.system_flag(:scheduler_wall_time, true)

    s = %{
      every: opts[:every_ms],
      keep: opts[:keep],
      max_agents: opts[:max_agents],
      max_hosts: opts[:max_hosts],
      ring: :queue.new(),
      n: 0,
      wall: :erlang.statistics(:scheduler_wall_time),
      totals: Tartarus.Events.totals(),
      host_totals: %{},
      agent_cont: nil,
      hosts: {},
      hosts_age: nil,
      host_offset: 0
    }

    {:ok, sample(s)}
  end

  @impl true
  def handle_call({:series, points}, _from, s) do
    {:reply, s.ring |> :queue.to_list() |> Enum.take(-points), s}
  end

  @impl true
  def handle_info(:sample, s), do: {:noreply, sample(s)}
  def handle_info(_other, s), do: {:noreply, s}

  defp sample(s) do
    t0 = Clock.machine_time(:microsecond)
    {:reductions, r0} = Process.info(self(), :reductions)
    Clock.machine_send_after(self(), :sample, s.every)
    mem = :erlang.memory()
    wall = :erlang.statistics(:scheduler_wall_time)
    totals = Tartarus.Events.totals()
    {boxes, cont} = mailboxes(s.agent_cont, s.max_agents)
    {s, all} = host_list(s)
    {hosts, offset} = host_slice(all, s.host_offset, s.max_hosts)
    {host_rows, hops, host_totals} = host_rows(hosts, boxes, s.host_totals)
    sorted = Enum.sort(hops)
    pct = fn q -> Tartarus.Percentile.sorted(sorted, q) end

    sample = %{
      t: Clock.machine_system_time(:millisecond),
      memory: %{
        total: mem[:total],
        processes: mem[:processes],
        ets: mem[:ets],
        binary: mem[:binary]
      },
      processes: :erlang.system_info(:process_count),
      run_queue: :erlang.statistics(:run_queue),
      run_queues: :erlang.statistics(:run_queue_lengths),
      sched_util: utilisation(s.wall, wall),
      mailbox_max: Enum.max_by(boxes, & &1.len, fn -> %{len: 0} end).len,
      mailboxes: longest(boxes, 5),
      hop_p50_us: pct.(0.5),
      hop_p90_us: pct.(0.9),
      hop_p99_us: pct.(0.99),
      arrivals: totals.arrivals - Map.get(s.totals, :arrivals, 0),
      refused: totals.refused - Map.get(s.totals, :refused, 0),
      hosts: host_rows
    }

    {:reductions, r1} = Process.info(self(), :reductions)

    sample =
      Map.merge(sample, %{
        cost_us: Clock.machine_time(:microsecond) - t0,
        cost_reductions: r1 - r0
      })

    {ring, n} =
      if s.n >= s.keep,
        do: {:queue.in(sample, :queue.drop(s.ring)), s.n},
        else: {:queue.in(sample, s.ring), s.n + 1}

    %{
      s
      | ring: ring,
        n: n,
        wall: wall,
        totals: totals,
        host_totals: host_totals,
        agent_cont: cont,
        host_offset: offset
    }
  end

  # Up to `max` agents of this node's agent table, from where the last sample stopped.
  defp mailboxes(cont, max) do
    result =
      case cont do
        nil -> select_agents(max)
        c -> :ets.select(c)
      end

    {list, next} =
      case result do
        {list, next} -> {list, next}
        :"$end_of_table" -> {[], nil}
      end

    list = if list == [] and cont != nil, do: elem(mailboxes(nil, max), 0), else: list

    boxes =
      for {id, pid, host, name} <- list,
          {:message_queue_len, len} <- [Process.info(pid, :message_queue_len)],
          do: %{id: id, name: TartarusDashboard.Feed.term(name), host: to_string(host), len: len}

    {boxes, next}
  end

  defp select_agents(max) do
    if :ets.whereis(Tartarus.AgentTable) == :undefined do
      :"$end_of_table"
    else
      :ets.select(
        Tartarus.AgentTable,
        [{{:"$1", :"$2", :"$3", :"$4", :_}, [], [{{:"$1", :"$2", :"$3", :"$4"}}]}],
        max
      )
    end
  end

  # This node's hosts (a tuple), listed again every @list_every samples: listing every host
  # of a node of 10,000 takes tens of ms, more than the rest of a sample. A host started
  # meanwhile is read from the next listing on; one stopped is skipped (its status fails).
  @list_every 30

  defp host_list(%{hosts: hosts, hosts_age: age} = s) when is_integer(age) and age < @list_every,
    do: {%{s | hosts_age: age + 1}, hosts}

  defp host_list(s) do
    hosts = List.to_tuple(Tartarus.hosts())
    {%{s | hosts: hosts, hosts_age: 1}, hosts}
  end

  # At most `max` of `all` (a tuple), from `offset` on (in turn, sample after sample).
  defp host_slice(all, offset, max) do
    n = tuple_size(all)

    if n <= max,
      do: {Tuple.to_list(all), 0},
      else: {for(i <- 0..(max - 1), do: elem(all, rem(offset + i, n))), rem(offset + max, n)}
  end

  defp host_rows(hosts, boxes, prev) do
    by_host = Enum.group_by(boxes, & &1.host, & &1.len)

    Enum.reduce(hosts, {%{}, [], prev}, fn {name, _} = h, {rows, hops, totals} ->
      case Tartarus.status(h, [:resident, :counts]) do
        %{counts: c} = st ->
          times = Tartarus.hop_times(h)
          times = if is_list(times), do: times, else: []
          sorted = Enum.sort(times)
          id = to_string(name)
          {a0, r0} = Map.get(prev, id, {c.arrivals, c.refused})

          row = %{
            residents: st.resident,
            arrivals: c.arrivals - a0,
            refused: c.refused - r0,
            mailbox_max: by_host |> Map.get(id, [0]) |> Enum.max(),
            hop_p50_us: Tartarus.Percentile.sorted(sorted, 0.5),
            hop_p99_us: Tartarus.Percentile.sorted(sorted, 0.99)
          }

          {Map.put(rows, id, row), times ++ hops, Map.put(totals, id, {c.arrivals, c.refused})}

        _ ->
          {rows, hops, totals}
      end
    end)
  end
end
