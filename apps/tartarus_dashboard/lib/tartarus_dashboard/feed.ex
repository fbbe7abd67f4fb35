defmodule TartarusDashboard.Feed do
  @moduledoc false
  # The dashboard's one subscriber to Tartarus.Events, with a budget: the platform sends it
  # at most max_batch events per batch_ms (the first of each window) and skips the others
  # without a message; the counts per type come from Tartarus.Events.type_totals/0, read at
  # every flush, so they are exact however many events were skipped. Per event received: a
  # few map updates (the agent's last known host, a bounded ring of recent events, a bounded
  # ring of hop times, the next batch). Every batch_ms the batch goes to the connected
  # streams as one server-sent event. Nothing here blocks an emitter, and if the mailbox
  # grows past @max_backlog (relayed events) the feed throws the backlog away and counts it.

  use GenServer

  alias Tartarus.Clock

  @max_backlog 20_000
  @hop_samples 2_048
  @slow_client 20

  def start_link(opts), do: GenServer.start_link(__MODULE__, opts)

  def stop(feed) do
    GenServer.stop(feed)
  catch
    :exit, _ -> :ok
  end

  # A stream (the calling HTTP handler process) joins: it gets {:sse, iodata} messages. A
  # message, not a call: a feed with a backlog of events takes the join when it gets to it,
  # and the stream has answered its head already (the page is "live" at once).
  def join(feed) do
    send(feed, {:join, self()})
    :ok
  end

  # Recent events, oldest first, filtered: %{type:, host:, agent:, since:, limit:}.
  def events(feed, filter), do: GenServer.call(feed, {:events, filter})

  # %{seq, dropped, clients, hop: %{count, p50_us, p90_us, p99_us, max_us}, counts: %{type => n}}
  def stats(feed), do: GenServer.call(feed, :stats)

  # The last host where the feed saw the agent (a host id), or nil.
  def place(feed, id), do: GenServer.call(feed, {:place, id})

  # Events per type per second over the last `seconds` (at most @rate_keep):
  # %{t: [unix second], counts: %{type => [n]}} (aligned, oldest first; the current second last).
  def rates(feed, seconds), do: GenServer.call(feed, {:rates, seconds})

  # Which id stands for which host address (%{host => id}); others are named by name.
  def names(feed, names), do: GenServer.cast(feed, {:names, names})

  # Subscribes remote nodes' events too (hosts of an emulation in peer mode).
  def watch_nodes(feed, nodes), do: GenServer.cast(feed, {:watch_nodes, nodes})

  @rate_keep 300
  @relay_ms 200
  @relay_max 1_000

  @doc false
  # Runs on another node: forwards that node's events to the feed, at most @relay_max
  # every @relay_ms in one message (the rest counted), until the feed goes.
  def relay(feed) do
    ref = Process.monitor(feed)
    Tartarus.Events.subscribe()
    Clock.machine_send_after(self(), :relay_flush, @relay_ms)
    relay_loop(feed, ref, [], 0, 0)
  end

  defp relay_loop(feed, ref, acc, n, dropped) do
    receive do
      {:tartarus_event, e} when n < @relay_max ->
        relay_loop(feed, ref, [e | acc], n + 1, dropped)

      {:tartarus_event, _} ->
        relay_loop(feed, ref, acc, n, dropped + 1)

      :relay_flush ->
        if n > 0 or dropped > 0, do: send(feed, {:tartarus_events, Enum.reverse(acc), dropped})
        Clock.machine_send_after(self(), :relay_flush, @relay_ms)
        relay_loop(feed, ref, [], 0, 0)

      {:DOWN, ^ref, _, _, _} ->
        :ok
    end
  end

  @impl true
  def init(opts) do
    Tartarus.Events.subscribe(budget: {opts[:max_batch], opts[:batch_ms]})
    Clock.machine_send_after(self(), :flush, opts[:batch_ms])

    {:ok,
     %{
       batch_ms: opts[:batch_ms],
       max_batch: opts[:max_batch],
       recent_max: opts[:recent],
       clients: %{},
       batch: %{},
       batch_n: 0,
       batch_seen: 0,
       sec: Clock.machine_system_time(:second),
       sec_counts: %{},
       rates: :queue.new(),
       rates_n: 0,
       batch_dropped: 0,
       seq: 0,
       dropped: 0,
       recent: :queue.new(),
       recent_n: 0,
       places: %{},
       hops: :queue.new(),
       hops_n: 0,
       counts: %{},
       watched: MapSet.new([node()]),
       names: %{},
       # Agents' processes of this node (pid => id), read again at most once a second when a
       # message's sender is not in it.
       pids: %{},
       pids_at: nil,
       # This node's events per type as last read, and how many of them arrived since.
       types: Tartarus.Events.type_totals(),
       received: 0
     }}
  end

  @impl true
  def handle_call({:events, f}, _from, s) do
    list =
      s.recent
      |> :queue.to_list()
      |> Enum.map(fn {seq, e} -> view(e, seq, s.names) end)
      |> Enum.filter(fn e ->
        e.seq > f.since and (f.type == nil or e.type == f.type) and
          (f.host == nil or e[:host] == f.host or e[:to] == f.host or e[:from] == f.host) and
          (f.agent == nil or e[:agent] == f.agent or e[:clone] == f.agent or
             e[:sender] == f.agent)
      end)

    {:reply, %{seq: s.seq, dropped: s.dropped, events: Enum.take(list, -f.limit)}, s}
  end

  def handle_call(:stats, _from, s) do
    sorted = s.hops |> :queue.to_list() |> Enum.sort()

    hop =
      case sorted do
        [] ->
          %{count: 0}

        _ ->
          %{
            count: length(sorted),
            p50_us: Tartarus.Percentile.sorted(sorted, 0.5),
            p90_us: Tartarus.Percentile.sorted(sorted, 0.9),
            p99_us: Tartarus.Percentile.sorted(sorted, 0.99),
            max_us: List.last(sorted)
          }
      end

    {:reply,
     %{
       seq: s.seq,
       dropped: s.dropped,
       clients: map_size(s.clients),
       hop: hop,
       counts: s.counts
     }, s}
  end

  def handle_call({:rates, seconds}, _from, s) do
    s = roll(s, Clock.machine_system_time(:second))
    done = s.rates |> :queue.to_list() |> Enum.take(-(seconds - 1))
    list = done ++ [{s.sec, s.sec_counts}]
    types = list |> Enum.flat_map(fn {_, c} -> Map.keys(c) end) |> Enum.uniq()

    {:reply,
     %{
       t: Enum.map(list, &elem(&1, 0)),
       counts: Map.new(types, fn t -> {t, Enum.map(list, fn {_, c} -> Map.get(c, t, 0) end)} end)
     }, s}
  end

  def handle_call({:place, id}, _from, s), do: {:reply, Map.get(s.places, id), s}

  @impl true
  def handle_cast({:names, names}, s), do: {:noreply, %{s | names: names}}

  def handle_cast({:watch_nodes, nodes}, s) do
    new = nodes |> Enum.uniq() |> Enum.reject(&MapSet.member?(s.watched, &1))
    Enum.each(new, &Node.spawn(&1, __MODULE__, :relay, [self()]))
    {:noreply, %{s | watched: Enum.into(new, s.watched)}}
  end

  @impl true
  def handle_info({:tartarus_event, e}, s) do
    s = take(e, %{s | received: s.received + 1}, false)

    if rem(s.seq, 1_000) == 0 do
      {:message_queue_len, n} = Process.info(self(), :message_queue_len)
      {:noreply, if(n > @max_backlog, do: shed(s), else: s)}
    else
      {:noreply, s}
    end
  end

  def handle_info({:tartarus_events, events, dropped}, s) do
    s = Enum.reduce(events, s, &take(&1, &2, true))
    {:noreply, %{s | dropped: s.dropped + dropped, batch_dropped: s.batch_dropped + dropped}}
  end

  def handle_info(:flush, s) do
    Clock.machine_send_after(self(), :flush, s.batch_ms)
    s = count_local(s)

    if s.batch_n > 0 and map_size(s.clients) > 0 do
      data =
        Tartarus.JSON.encode!(%{
          seq: s.seq,
          dropped: s.batch_dropped,
          seen: s.batch_seen,
          events:
            s.batch
            |> Map.values()
            |> Enum.sort()
            |> Enum.map(fn {seq, e} -> view(e, seq, s.names) end)
        })

      msg = {:sse, ["event: batch\ndata: ", data, "\n\n"]}

      Enum.each(s.clients, fn {pid, _} ->
        case Process.info(pid, :message_queue_len) do
          {:message_queue_len, n} when n < @slow_client -> send(pid, msg)
          _ -> :ok
        end
      end)
    end

    {:noreply,
     %{
       roll(s, Clock.machine_system_time(:second))
       | batch: %{},
         batch_n: 0,
         batch_dropped: 0,
         batch_seen: 0
     }}
  end

  def handle_info({:join, pid}, s) when is_pid(pid) do
    ref = Process.monitor(pid)
    {:noreply, %{s | clients: Map.put(s.clients, pid, ref)}}
  end

  def handle_info({:DOWN, _ref, :process, pid, _}, s),
    do: {:noreply, %{s | clients: Map.delete(s.clients, pid)}}

  def handle_info(_other, s), do: {:noreply, s}

  # Per event only places and rings of raw events, and counts for a `relayed` one (another
  # node's; this node's come from its totals at each flush). The conversion to JSON-able
  # views happens when a batch goes out or /api/events asks, for at most a batch or a ring.
  defp take(e, s, relayed) when is_map(e) do
    seq = s.seq + 1
    t = Map.get(e, :type)
    h = name(Map.get(e, :host), s.names)
    s = %{s | seq: seq}
    s = if relayed, do: add_counts(s, %{t => 1}), else: s
    s = track(t, e, h, s)
    {e, s} = sender(e, s)

    s =
      case e do
        %{type: :arrival, hop_us: us} when is_integer(us) -> hop(us, s)
        _ -> s
      end

    raw = {seq, e}

    {recent, n} =
      if s.recent_n >= s.recent_max,
        do: {:queue.in(raw, :queue.drop(s.recent)), s.recent_n},
        else: {:queue.in(raw, s.recent), s.recent_n + 1}

    s = %{s | recent: recent, recent_n: n}

    seen = s.batch_seen + 1
    s = %{s | batch_seen: seen}

    # A batch is a uniform sample of the events of its interval (reservoir sampling): at most
    # max_batch of them, the others counted as skipped.
    cond do
      s.batch_n < s.max_batch ->
        %{s | batch: Map.put(s.batch, s.batch_n, raw), batch_n: s.batch_n + 1}

      # (A hash of the sequence number stands in for a random draw: as uniform here, and
      # without a random state to read and write per event.)
      (j = :erlang.phash2(seq, seen)) < s.max_batch ->
        %{
          s
          | batch: Map.put(s.batch, j, raw),
            batch_dropped: s.batch_dropped + 1,
            dropped: s.dropped + 1
        }

      true ->
        %{s | batch_dropped: s.batch_dropped + 1, dropped: s.dropped + 1}
    end
  end

  # This node's events since the last flush, per type, from the platform's counts: added to
  # the totals and to the current second; those not received were skipped (the budget).
  defp count_local(s) do
    now = Tartarus.Events.type_totals()

    delta = for {t, n} <- now, (d = n - Map.get(s.types, t, 0)) > 0, into: %{}, do: {t, d}

    skipped = max(Enum.sum(Map.values(delta)) - s.received, 0)

    %{
      add_counts(s, delta)
      | types: now,
        received: 0,
        dropped: s.dropped + skipped,
        batch_dropped: s.batch_dropped + skipped
    }
  end

  defp add_counts(s, counts) do
    s = roll(s, Clock.machine_system_time(:second))
    add = fn acc -> Map.merge(acc, counts, fn _t, a, b -> a + b end) end
    %{s | counts: add.(s.counts), sec_counts: add.(s.sec_counts)}
  end

  defp roll(%{sec: sec} = s, sec), do: s

  defp roll(s, now) do
    # Seconds without events are kept as empty (at most the ring's size of them).
    gap = min(now - s.sec - 1, @rate_keep)
    closed = [{s.sec, s.sec_counts} | for(i <- gap..1//-1, gap > 0, do: {now - i, %{}})]

    {q, n} =
      Enum.reduce(closed, {s.rates, s.rates_n}, fn x, {q, n} ->
        if n >= @rate_keep, do: {:queue.in(x, :queue.drop(q)), n}, else: {:queue.in(x, q), n + 1}
      end)

    %{s | sec: now, sec_counts: %{}, rates: q, rates_n: n}
  end

  defp track(t, %{agent: a}, h, s) when t in [:created, :arrival],
    do: %{s | places: Map.put(s.places, a, h)}

  defp track(:clone, %{clone: c, to: to}, _h, s) when is_binary(c),
    do: %{s | places: Map.put(s.places, c, name(to, s.names))}

  defp track(t, %{agent: a}, _h, s) when t in [:kill, :stopped, :removed],
    do: %{s | places: Map.delete(s.places, a)}

  defp track(_, _, _, s), do: s

  # A message's sender: the id of the agent whose process sent it (an agent of this node), or
  # nil (a shell, the dashboard, another node's process).
  defp sender(%{type: :message, sender: pid} = e, s) when is_pid(pid) do
    {id, s} = agent_of(pid, s)
    {Map.put(e, :sender, id), s}
  end

  defp sender(e, s), do: {e, s}

  defp agent_of(pid, s) do
    now = Clock.machine_time(:millisecond)

    cond do
      Map.has_key?(s.pids, pid) ->
        {s.pids[pid], s}

      node(pid) != node() or (s.pids_at != nil and now - s.pids_at < 1_000) ->
        {nil, s}

      true ->
        pids = Map.new(Tartarus.agents(), &{&1.pid, &1.id})
        {Map.get(pids, pid), %{s | pids: pids, pids_at: now}}
    end
  end

  defp hop(us, s) do
    if s.hops_n >= @hop_samples,
      do: %{s | hops: :queue.in(us, :queue.drop(s.hops))},
      else: %{s | hops: :queue.in(us, s.hops), hops_n: s.hops_n + 1}
  end

  # Throws the backlog of events away (counted), so the mailbox stays bounded.
  defp shed(s) do
    n = drain(0)
    %{s | dropped: s.dropped + n, batch_dropped: s.batch_dropped + n}
  end

  defp drain(n) do
    receive do
      {:tartarus_event, _} -> drain(n + 1)
    after
      0 -> n
    end
  end

  @keys [
    :agent,
    :module,
    :from,
    :to,
    :hop_us,
    :hops,
    :bytes,
    :code_bytes,
    :reason,
    :clone,
    :restarts,
    :service,
    :kind,
    :name,
    :messages,
    :sender,
    :message
  ]

  # An event as JSON-able data: hosts become host ids (their names), terms become text.
  @doc false
  def view(e, seq, names \\ %{}) do
    base = %{seq: seq, type: e[:type], host: name(e[:host], names), time: e[:time]}

    Enum.reduce(@keys, base, fn k, acc ->
      case Map.fetch(e, k) do
        {:ok, v} -> Map.put(acc, k, value(k, v, names))
        :error -> acc
      end
    end)
  end

  defp value(k, v, names) when k in [:from, :to], do: name(v, names)
  defp value(:module, v, _) when is_atom(v), do: inspect(v)
  defp value(_k, v, _), do: term(v)

  defp name(h, names) do
    case names do
      %{^h => id} -> id
      _ -> host_id(h)
    end
  end

  @doc false
  def host_id({name, node}) when is_atom(node), do: to_string(name)
  def host_id(nil), do: nil
  def host_id(name) when is_atom(name) or is_binary(name), do: to_string(name)
  def host_id(other), do: inspect(other, limit: 6, printable_limit: 60)

  @doc false
  def term(v) when is_binary(v) do
    if String.printable?(v) and byte_size(v) <= 200, do: v, else: inspect(v, limit: 6)
  end

  def term(v) when is_number(v) or is_boolean(v) or is_nil(v), do: v
  def term(v) when is_atom(v), do: Atom.to_string(v)
  def term(v), do: inspect(v, limit: 8, printable_limit: 80)
end
