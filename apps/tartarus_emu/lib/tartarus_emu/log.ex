defmodule TartarusEmu.Log do
  @moduledoc """
  The log server: an event log with a step clock, after the thesis's log server that counts
  steps without interfering with the mechanism.

  ## How it works

  On every BEAM node of a network the log runs a forwarder that subscribes to the node's
  platform events (`Tartarus.Events`), keeps the events of the network's hosts, counts them
  and sends the counts to the log every `:flush_ms` (default 50 ms). Emitting an event is a
  `send/2` to the forwarder, so agents never wait for the log, and the log changes nothing
  they see: it only listens.

  The log keeps a **step clock**. The scenario runner advances it with `tick/1` once a step
  is over; `tick/1` first collects everything the forwarders have, so every event is
  stamped with the step it happened in (in the runner's step-synchronous scenarios). Counts
  are kept per counter, per host, per directed link and per step (see
  `TartarusEmu.Log.Counts` for the keys and their meaning); they come only from the
  platform's events, never from a second bookkeeping. Raw events are kept only with
  `keep_events: true`, up to `:max_events` (the rest are counted as dropped), so a run of a
  million migrations costs memory only for its counts.

  ## Example

      {:ok, net} = TartarusEmu.Network.start(TartarusEmu.Topology.ring(5))
      {:ok, log} = TartarusEmu.Log.start(net, keep_events: true)
      # ... agents move ...
      1 = TartarusEmu.Log.tick(log)
      TartarusEmu.Log.counts(log).totals.departures
      TartarusEmu.Log.write_csv!(log, "results/run")
      TartarusEmu.Log.stop(log)

  A peer node that restarts (`TartarusEmu.Network.restart_node/2`) gets a new forwarder
  when it comes back up.
  """

  use GenServer

  alias TartarusEmu.Log.{Counts, Forwarder}
  alias Tartarus.Clock
  alias TartarusTools.Report

  @typedoc "A running log."
  @type t :: pid()

  @schema [
    keep_events: [type: :boolean, default: false, doc: "keep raw events (bounded)"],
    max_events: [type: :non_neg_integer, default: 100_000, doc: "raw events kept at most"],
    flush_ms: [type: :pos_integer, default: 50, doc: "forwarders send their counts this often"]
  ]

  @doc """
  Starts a log listening to the hosts of `network` (a `TartarusEmu.Network`, or a list of
  host addresses). The log is linked to the caller. Options:

  #{Tartarus.Options.docs(@schema)}
  """
  @spec start(TartarusEmu.Network.t() | [Tartarus.host()], keyword()) ::
          {:ok, t()} | {:error, term()}
  def start(network, opts \\ []) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusEmu.Log.start/2") do
      hosts =
        case network do
          %TartarusEmu.Network{} = net -> TartarusEmu.Network.host_list(net)
          list when is_list(list) -> Enum.map(list, &Tartarus.Host.address/1)
        end

      GenServer.start_link(__MODULE__, {hosts, opts})
    end
  end

  @doc """
  Stops the log and its forwarders. A log that is already gone (or going: it stops with its
  network) is fine: `:ok` either way.
  """
  @spec stop(t()) :: :ok
  def stop(log) do
    GenServer.stop(log)
  catch
    :exit, _ -> :ok
  end

  @doc """
  Ends the current step: collects what the forwarders have (stamped with the current step),
  then advances the clock. Returns the new step. The clock starts at 0 (setup).
  """
  @spec tick(t()) :: non_neg_integer()
  def tick(log), do: GenServer.call(log, :tick, :infinity)

  @doc "Collects what the forwarders have, without advancing the clock."
  @spec sync(t()) :: :ok
  def sync(log), do: GenServer.call(log, :sync, :infinity)

  @doc "The current step."
  @spec step(t()) :: non_neg_integer()
  def step(log), do: GenServer.call(log, :step)

  @doc """
  The counts so far (call `sync/1` first to include the last few milliseconds):
  `%{totals:, hosts:, links:, steps:}` as described in `TartarusEmu.Log.Counts.nest/1`.
  """
  @spec counts(t()) :: map()
  def counts(log), do: GenServer.call(log, :counts, :infinity)

  @doc """
  The totals of every counter (names as in `Tartarus.Events`), over the whole run or, given
  `step`, in that step only. Cheap: it does not build the nested per-host maps.
  """
  @spec totals(t(), non_neg_integer() | :all) :: %{atom() => non_neg_integer()}
  def totals(log, step \\ :all), do: GenServer.call(log, {:totals, step}, :infinity)

  @doc """
  The totals once the network is quiet: syncs, and syncs again (every 10 ms, for at most
  `timeout_ms`) until every broadcast message sent has been received and every departure
  has arrived. A broadcast is received, and an arrival counted, a moment after the call
  that sent it returned, so totals read right after an experiment's last step can miss
  them. On a network that loses messages (killed nodes, lossy links) the counts never
  match: the totals at the timeout are returned.
  """
  @spec settled_totals(t(), non_neg_integer()) :: %{atom() => non_neg_integer()}
  def settled_totals(log, timeout_ms \\ 2_000) do
    :ok = sync(log)
    t = totals(log)

    settled =
      Map.get(t, :broadcast_messages, 0) == Map.get(t, :broadcasts_received, 0) and
        Map.get(t, :departures, 0) == Map.get(t, :arrivals, 0)

    if settled or timeout_ms <= 0 do
      t
    else
      Clock.sleep(10)
      settled_totals(log, timeout_ms - 10)
    end
  end

  @doc "The flat counts (`TartarusEmu.Log.Counts`)."
  @spec raw_counts(t()) :: Counts.t()
  def raw_counts(log), do: GenServer.call(log, :raw_counts, :infinity)

  @doc """
  The raw events kept (with `keep_events: true`), oldest first, each with its `:step`; and
  how many were dropped beyond `:max_events`.
  """
  @spec events(t()) :: {[map()], non_neg_integer()}
  def events(log), do: GenServer.call(log, :events, :infinity)

  @doc """
  Writes the log as CSV into `dir`: `log_steps.csv` (counters per step), `log_hosts.csv`
  (counters per host), `log_links.csv` (messages and bytes per directed link) and, when
  events are kept, `log_events.csv`. Returns the paths.
  """
  @spec write_csv!(t(), Path.t()) :: [Path.t()]
  def write_csv!(log, dir) do
    :ok = sync(log)
    c = counts(log)
    names = Tartarus.Events.counter_names()

    steps =
      c.steps
      |> Enum.sort()
      |> Enum.map(fn {s, m} -> [s | Enum.map(names, &Map.get(m, &1, 0))] end)

    hosts =
      c.hosts
      |> Enum.sort()
      |> Enum.map(fn {{name, node}, m} ->
        [to_string(name), node | Enum.map(names, &Map.get(m, &1, 0))]
      end)

    links =
      c.links
      |> Enum.sort()
      |> Enum.map(fn {{from, to}, m} ->
        [host_text(from), host_text(to), Map.get(m, :messages, 0), Map.get(m, :bytes, 0)]
      end)

    paths = [
      Report.write_csv!(dir, "log_steps", ["step" | Enum.map(names, &to_string/1)], steps),
      Report.write_csv!(
        dir,
        "log_hosts",
        ["host", "node" | Enum.map(names, &to_string/1)],
        hosts
      ),
      Report.write_csv!(dir, "log_links", ["from", "to", "messages", "bytes"], links)
    ]

    case events(log) do
      {[], _} ->
        paths

      {events, _} ->
        rows =
          Enum.map(events, fn e ->
            [
              e.step,
              Map.get(e, :time),
              e.type,
              host_text(e.host),
              Map.get(e, :agent),
              host_text(Map.get(e, :to) || Map.get(e, :from)),
              Map.get(e, :bytes)
            ]
          end)

        header = ["step", "time_us", "type", "host", "agent", "peer_host", "bytes"]
        paths ++ [Report.write_csv!(dir, "log_events", header, rows)]
    end
  end

  defp host_text({name, _node}), do: to_string(name)
  defp host_text(nil), do: nil
  defp host_text(other) when is_atom(other) or is_binary(other), do: to_string(other)
  defp host_text(other), do: inspect(other)

  # -- server ------------------------------------------------------------------------

  @impl true
  def init({hosts, opts}) do
    Process.flag(:message_queue_data, :off_heap)
    by_node = Enum.group_by(hosts, &elem(&1, 1))
    if Enum.any?(Map.keys(by_node), &(&1 != node())), do: :net_kernel.monitor_nodes(true)

    s = %{
      by_node: by_node,
      forwarders: %{},
      opts: opts,
      step: 0,
      counts: %{},
      events: [],
      kept: 0,
      dropped: 0
    }

    {:ok, Enum.reduce(Map.keys(by_node), s, &attach(&2, &1))}
  end

  defp attach(s, node) do
    args = [self(), Map.fetch!(s.by_node, node), s.opts[:keep_events], s.opts[:flush_ms]]

    result =
      if node == node(),
        do: apply(Forwarder, :start, args),
        else: :erpc.call(node, Forwarder, :start, args, 15_000)

    case result do
      {:ok, pid} ->
        Process.monitor(pid)
        %{s | forwarders: Map.put(s.forwarders, node, pid)}

      _ ->
        s
    end
  catch
    _, _ -> s
  end

  @impl true
  def handle_call(:tick, _from, s) do
    s = collect(s)
    {:reply, s.step + 1, %{s | step: s.step + 1}}
  end

  def handle_call(:sync, _from, s), do: {:reply, :ok, collect(s)}
  def handle_call(:step, _from, s), do: {:reply, s.step, s}
  def handle_call(:counts, _from, s), do: {:reply, Counts.nest(s.counts), s}
  def handle_call(:raw_counts, _from, s), do: {:reply, s.counts, s}

  def handle_call({:totals, step}, _from, s) do
    key = fn name -> if step == :all, do: {:total, name}, else: {:step, step, name} end
    {:reply, Map.new(Tartarus.Events.counter_names(), &{&1, Map.get(s.counts, key.(&1), 0)}), s}
  end

  def handle_call(:events, _from, s), do: {:reply, {Enum.reverse(s.events), s.dropped}, s}

  @impl true
  def handle_info({:batch, _pid, delta, events}, s), do: {:noreply, batch(s, delta, events)}

  def handle_info({:nodeup, node}, s) do
    if Map.has_key?(s.by_node, node) and not Map.has_key?(s.forwarders, node),
      do: {:noreply, attach(s, node)},
      else: {:noreply, s}
  end

  def handle_info({:DOWN, _, :process, pid, _}, s) do
    {:noreply, %{s | forwarders: Map.reject(s.forwarders, fn {_, p} -> p == pid end)}}
  end

  def handle_info(_msg, s), do: {:noreply, s}

  @impl true
  def terminate(_reason, s) do
    Enum.each(s.forwarders, fn {_, pid} -> send(pid, :stop) end)
  end

  defp batch(s, delta, events) do
    s = %{s | counts: Counts.merge(s.counts, Counts.stamp(delta, s.step))}

    case events do
      [] ->
        s

      _ ->
        room = s.opts[:max_events] - s.kept
        n = length(events)
        # `events` is newest first; keep the oldest ones that fit.
        kept = events |> Enum.take(-min(room, n)) |> Enum.map(&Map.put(&1, :step, s.step))

        %{
          s
          | events: kept ++ s.events,
            kept: s.kept + length(kept),
            dropped: s.dropped + n - length(kept)
        }
    end
  end

  # Asks every forwarder for its batch and waits for all of them (a forwarder's batch comes
  # before its answer; a forwarder that dies is skipped).
  defp collect(s) do
    pending =
      Map.new(s.forwarders, fn {_node, pid} ->
        ref = Process.monitor(pid)
        send(pid, {:flush, self(), ref})
        {ref, pid}
      end)

    await(s, pending)
  end

  defp await(s, pending) when map_size(pending) == 0, do: s

  defp await(s, pending) do
    receive do
      {:batch, _pid, delta, events} ->
        await(batch(s, delta, events), pending)

      {ref, :flushed, _pid} when is_map_key(pending, ref) ->
        Process.demonitor(ref, [:flush])
        await(s, Map.delete(pending, ref))

      {:DOWN, ref, :process, _, _} when is_map_key(pending, ref) ->
        await(s, Map.delete(pending, ref))
    end
  end
end
