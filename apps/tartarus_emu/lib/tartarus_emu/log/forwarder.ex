defmodule TartarusEmu.Log.Forwarder do
  @moduledoc false
  # Runs on every BEAM node of a network: subscribes to the node's Tartarus events, keeps
  # those of the network's hosts, counts them (TartarusEmu.Log.Counts) and sends the counts
  # (and raw events, when the log keeps them) to the log every `flush_ms`, or at once when the
  # log asks (`{:flush, log, ref}`, answered with `{ref, :flushed, self()}` after the batch).
  # Emitters only `send/2` to it: nothing an agent does waits for the log.
  #
  # Log protocol:  F -> L {:batch, f_pid, counts_delta, [event]}   (events newest first)
  #                L -> F {:flush, l_pid, ref};  F -> L {ref, :flushed, f_pid}

  alias TartarusEmu.Log.Counts
  alias Tartarus.Clock
  alias Tartarus.MachineClock
  require Tartarus.MachineClock

  # Called on the forwarder's node (by :erpc). Returns its pid once it is subscribed.
  def start(log, hosts, keep_events?, flush_ms) do
    caller = self()
    ref = make_ref()

    # Off-heap mailbox: a burst of 100,000 concurrent migrations queues 200,000 events
    # here, which must not be copied by every garbage collection of this process.
    pid =
      :erlang.spawn_opt(
        fn ->
          :ok = Tartarus.Events.subscribe()
          mref = Process.monitor(log)
          send(caller, {ref, :subscribed})
          Clock.send_after(self(), :tick, flush_ms)

          loop(%{
            log: log,
            mref: mref,
            hosts: MapSet.new(hosts),
            keep?: keep_events?,
            flush_ms: flush_ms,
            delta: %{},
            events: []
          })
        end,
        [{:message_queue_data, :off_heap}]
      )

    MachineClock.receive do
      {^ref, :subscribed} -> {:ok, pid}
    after
      10_000 -> {:error, :forwarder_timeout}
    end
  end

  defp loop(s) do
    mref = s.mref

    receive do
      {:tartarus_event, %{host: host} = e} ->
        if MapSet.member?(s.hosts, host) do
          events = if s.keep?, do: [e | s.events], else: s.events
          loop(%{s | delta: Counts.add(s.delta, e), events: events})
        else
          loop(s)
        end

      :tick ->
        Clock.send_after(self(), :tick, s.flush_ms)
        loop(flush(s))

      {:flush, from, ref} ->
        s = flush(s)
        send(from, {ref, :flushed, self()})
        loop(s)

      {:DOWN, ^mref, _, _, _} ->
        Tartarus.Events.unsubscribe()

      :stop ->
        Tartarus.Events.unsubscribe()

      _ ->
        loop(s)
    end
  end

  defp flush(%{delta: d, events: []} = s) when map_size(d) == 0, do: s

  defp flush(s) do
    send(s.log, {:batch, self(), s.delta, s.events})
    %{s | delta: %{}, events: []}
  end
end
