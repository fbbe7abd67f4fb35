defmodule TartarusTools.Bench.Busy do
  @moduledoc """
  Reaching a busy agent: `mix tartarus.bench busy` (issue 9, item 7).

  Two peer nodes, one host each, and one agent (`TartarusTools.Bench.Busy.Hopper`) that
  hops between them continuously: it moves on at every arrival and after every message it
  takes. `:senders` processes (default 4), on the first node, post `:messages` messages in
  all (default 50,000) to it with `Tartarus.post/3`, each sender one at a time (so each
  sender's order is defined), always through the agent's home host (forwarding pointers
  lead the way). Each message is `{:m, sender, seq}`.

  The agent records every message it takes in a bitmap per sender (it travels with it):
  a message whose bit is already set is a *duplicate*; one whose `seq` is below the
  sender's highest seen so far breaks the sender's *order*. At the end the hosts' stores
  tell the agent to stop hopping, and its state is read.

  Keys: `messages` (asked), `sent` (posts made before the time budget ran out),
  `acknowledged` (post returned `:ok`), `delivered` (distinct messages in the agent's
  state), `delivered_exactly_once` (taken once), `duplicates`, `acknowledged_missing`
  (`:ok` but not in the state: must be 0), `delivered_despite_error` (an error other than
  `:timeout` returned, which means "not delivered", but the agent had it: must be 0),
  `unknown_outcomes` (posts that returned `{:error, :timeout}`: outcome unknown) and
  `unknown_delivered` (of those, how many the agent had), `failures` (error reason =>
  count), `order_kept` (true when no
  sender's message came after a later one of the same sender), `out_of_order`,
  `delivered_pct`, `hops` (the agent's), `wall_ms`, `posts_per_s`.
  """

  alias TartarusTools.Bench.Busy.Hopper
  alias Tartarus.Clock
  require Tartarus.Clock

  @doc """
  Runs the busy-agent benchmark on two fresh peer nodes. Options: `:messages` (default
  50,000), `:senders` (4), `:timeout` (per post, ms, default 5,000), `:max_seconds`
  (time budget for sending, default 120: senders stop there and the rest counts as not
  sent), `:dwell_ms` (how long the agent stays on each host before it moves on, default 0:
  it moves on at once), `:via` (`:post`, the default, or `:cast`: each sender casts its
  messages `:pace_ms` apart, default 2, with `Tartarus.cast/3`, and the keys
  `cast_failed_reports`, `cast_unknown_reports` and `reported_failed_yet_delivered` say
  whether a failure report ever meant anything but "not delivered"; order is not kept
  between casts, which are delivered by separate processes).
  """
  @spec run(keyword()) :: map()
  def run(opts) do
    TartarusTools.Bench.with_peers(false, fn {pa, _}, {pb, _} ->
      {:ok, h2} = :peer.call(pb, Tartarus, :start_host, [:busy_b], 30_000)
      :peer.call(pa, __MODULE__, :drive, [h2, opts], :infinity)
    end)
  end

  @doc false
  # Runs on the first peer; `h2` is the other host. Also usable with both hosts in one VM.
  def drive(h2, opts) do
    messages = Keyword.get(opts, :messages, 50_000)
    senders = Keyword.get(opts, :senders, 4)
    timeout = Keyword.get(opts, :timeout, 5_000)
    budget_ms = Keyword.get(opts, :max_seconds, 120) * 1000
    {:ok, h1} = Tartarus.start_host(:"busy_a#{System.unique_integer([:positive])}")

    try do
      :ok = Tartarus.connect(h1, h2)
      per = for s <- 1..senders, do: div(messages, senders) + if(s <= rem(messages, senders), do: 1, else: 0)
      state = Hopper.new(h1, h2, per, Keyword.get(opts, :dwell_ms, 0))
      {:ok, id} = Tartarus.create_mobile_agent(h1, Hopper, state)
      :ok = Tartarus.post({id, h1}, :go)
      t0 = Clock.machine_time(:millisecond)
      deadline = t0 + budget_ms

      via = Keyword.get(opts, :via, :post)

      results =
        per
        |> Enum.with_index()
        |> Enum.map(fn {n, s} ->
          Task.async(fn ->
            if via == :cast,
              do: cast_all({id, h1}, s, n, Keyword.get(opts, :pace_ms, 2), deadline),
              else: send_all({id, h1}, s, n, timeout, deadline)
          end)
        end)
        |> Task.await_many(:infinity)

      wall_ms = max(Clock.machine_time(:millisecond) - t0, 1)

      for h <- [h1, h2], do: Tartarus.store_put(h, :busy_stop, true)
      final = final_state({id, h1}, 100)
      summary = summarize(final, results, per, messages, wall_ms)
      if via == :cast, do: cast_summary(summary, results), else: summary
    after
      Tartarus.stop_host(h1)
    end
  end

  # Casts (Tartarus.cast/3) `n` messages, `pace_ms` apart, then collects the reports of the
  # delivering processes (each gives up after 5 s): nothing is acknowledged to a cast, so a
  # message counts as sent, and its failure reports are checked against what the agent had.
  defp cast_all(ref, s, n, pace_ms, deadline) do
    sent =
      Enum.reduce_while(0..(n - 1)//1, 0, fn seq, sent ->
        if Clock.machine_time(:millisecond) > deadline do
          {:halt, sent}
        else
          :ok = Tartarus.cast(ref, {:m, s, seq}, self())
          if pace_ms > 0, do: Clock.sleep(pace_ms)
          {:cont, sent + 1}
        end
      end)

    until = Clock.monotonic_time(:millisecond) + 6_000
    reports = collect_reports(until, %{failed: 0, unknown: 0})
    %{sent: sent, ok: [], errors: [], reports: reports}
  end

  defp collect_reports(until, acc) do
    Clock.receive do
      {:tartarus_cast_failed, _agent, _reason} ->
        collect_reports(until, %{acc | failed: acc.failed + 1})

      {:tartarus_cast_unknown, _agent, _reason} ->
        collect_reports(until, %{acc | unknown: acc.unknown + 1})
    after
      max(until - Clock.monotonic_time(:millisecond), 0) -> acc
    end
  end

  # A failure report must mean "not delivered": with every message sent once, the agent may
  # hold at most sent - failed of them.
  defp cast_summary(summary, results) do
    failed = Enum.sum(Enum.map(results, & &1.reports.failed))
    unknown = Enum.sum(Enum.map(results, & &1.reports.unknown))

    Map.merge(summary, %{
      via: :cast,
      cast_failed_reports: failed,
      cast_unknown_reports: unknown,
      reported_failed_yet_delivered: max(summary.delivered + failed - summary.sent, 0)
    })
  end

  defp send_all(ref, s, n, timeout, deadline) do
    Enum.reduce(0..(n - 1)//1, %{sent: 0, ok: [], errors: []}, fn seq, acc ->
      if Clock.machine_time(:millisecond) > deadline do
        acc
      else
        case Tartarus.post(ref, {:m, s, seq}, timeout) do
          :ok -> %{acc | sent: acc.sent + 1, ok: [seq | acc.ok]}
          {:error, reason} -> %{acc | sent: acc.sent + 1, errors: [{seq, reason} | acc.errors]}
        end
      end
    end)
  end

  # The agent's state once it stopped hopping (it stops at its next arrival or message).
  defp final_state(ref, tries) do
    Tartarus.post(ref, :poke)

    case Tartarus.agent_info(ref) do
      {:ok, %{state: %{stopped: true} = s, hops: hops}} ->
        Map.put(s, :hops, hops)

      _ when tries > 0 ->
        Clock.sleep(100)
        final_state(ref, tries - 1)

      other ->
        raise "the busy agent could not be read: #{inspect(other)}"
    end
  end

  defp summarize(final, results, per, messages, wall_ms) do
    rows =
      for {{r, n}, s} <- Enum.with_index(Enum.zip(results, per)) do
        bits = Map.get(final.bits, s, <<0::size(n)>>)
        got = fn seq -> Hopper.bit(bits, seq) end
        delivered = Enum.count(0..(n - 1)//1, got)
        missing = Enum.count(r.ok, &(not got.(&1)))
        # A failure report means "not delivered"; a timeout means "unknown" (Tartarus.post/3).
        {unknown, failed} = Enum.split_with(r.errors, fn {_, reason} -> reason == :timeout end)
        despite = Enum.count(failed, fn {seq, _} -> got.(seq) end)
        unknown_delivered = Enum.count(unknown, fn {seq, _} -> got.(seq) end)

        %{
          sent: r.sent,
          ok: length(r.ok),
          delivered: delivered,
          missing: missing,
          despite: despite,
          unknown: length(unknown),
          unknown_delivered: unknown_delivered
        }
      end

    sum = fn key -> Enum.sum(Enum.map(rows, &Map.fetch!(&1, key))) end

    failures =
      results
      |> Enum.flat_map(& &1.errors)
      |> Enum.frequencies_by(fn {_, reason} -> inspect(reason) end)

    delivered = sum.(:delivered)
    once = delivered - final.dup_messages

    %{
      messages: messages,
      senders: length(per),
      sent: sum.(:sent),
      acknowledged: sum.(:ok),
      delivered: delivered,
      delivered_exactly_once: once,
      duplicates: final.duplicates,
      acknowledged_missing: sum.(:missing),
      delivered_despite_error: sum.(:despite),
      unknown_outcomes: sum.(:unknown),
      unknown_delivered: sum.(:unknown_delivered),
      failures: failures,
      failed: Enum.sum(Map.values(failures)),
      order_kept: final.out_of_order == 0,
      out_of_order: final.out_of_order,
      delivered_pct: Float.round(100 * once / max(messages, 1), 3),
      hops: final.hops,
      dwell_ms: final.dwell_ms,
      wall_ms: wall_ms,
      posts_per_s: round(sum.(:sent) * 1000 / wall_ms)
    }
  end
end

defmodule TartarusTools.Bench.Busy.Hopper do
  @moduledoc """
  The agent of `TartarusTools.Bench.Busy`: hops between two hosts continuously (at every
  arrival and after every message) and records the messages `{:m, sender, seq}` it takes
  in a bitmap per sender, counting duplicates and messages that came after a later one of
  the same sender. It stops hopping once its host's store holds `busy_stop: true`.
  """
  use Tartarus.Agent

  @doc "The initial state for two hosts and, per sender (0, 1, ...), its message count."
  @spec new(Tartarus.host(), Tartarus.host(), [non_neg_integer()]) :: map()
  def new(a, b, per, dwell_ms \\ 0) do
    bits = per |> Enum.with_index() |> Map.new(fn {n, s} -> {s, <<0::size(n)>>} end)

    %{
      a: a,
      b: b,
      bits: bits,
      last: %{},
      duplicates: 0,
      dup_messages: 0,
      out_of_order: 0,
      dwell_ms: dwell_ms,
      stopped: false
    }
  end

  @doc "True if bit `i` of `bits` is set."
  @spec bit(bitstring(), non_neg_integer()) :: boolean()
  def bit(bits, i) when i < bit_size(bits) do
    <<_::bitstring-size(i), b::1, _::bitstring>> = bits
    b == 1
  end

  def bit(_bits, _i), do: false

  @impl true
  def init(s), do: {:stay, s}

  @impl true
  def handle_arrival(_ctx, %{dwell_ms: 0} = s), do: next(s)

  def handle_arrival(_ctx, s) do
    Tartarus.Clock.send_after(self(), :hop, s.dwell_ms)
    {:stay, s}
  end

  @impl true
  def handle_message({:m, sender, seq}, _from, s), do: after_message(record(s, sender, seq))
  def handle_message(:go, _from, s), do: next(s)
  def handle_message(_other, _from, s), do: after_message(s)

  @impl true
  def handle_info(:hop, s), do: next(s)
  def handle_info(_other, s), do: {:stay, s}

  # Without a dwell time every message is followed by a hop; with one, the timer set on
  # arrival makes the next hop.
  defp after_message(%{dwell_ms: 0} = s), do: next(s)

  defp after_message(s) do
    if Tartarus.Agent.store_get(:busy_stop, false),
      do: {:stay, %{s | stopped: true}},
      else: {:stay, s}
  end

  defp next(s) do
    if Tartarus.Agent.store_get(:busy_stop, false) do
      {:stay, %{s | stopped: true}}
    else
      here = Tartarus.Agent.host()
      {:move, if(here == s.a, do: s.b, else: s.a), s}
    end
  end

  defp record(s, sender, seq) do
    bits = Map.get(s.bits, sender, <<>>)
    last = Map.get(s.last, sender, -1)
    s = if seq < last, do: %{s | out_of_order: s.out_of_order + 1}, else: s
    s = %{s | last: Map.put(s.last, sender, max(seq, last))}

    cond do
      seq >= bit_size(bits) ->
        s

      bit(bits, seq) ->
        # The first extra copy of a message counts it as duplicated; every copy counts.
        first? = not Map.has_key?(Map.get(s, :dup_seen, %{}), {sender, seq})

        %{
          s
          | duplicates: s.duplicates + 1,
            dup_messages: s.dup_messages + if(first?, do: 1, else: 0)
        }
        |> Map.update(:dup_seen, %{{sender, seq} => true}, &Map.put(&1, {sender, seq}, true))

      true ->
        <<pre::bitstring-size(seq), _::1, post::bitstring>> = bits
        %{s | bits: Map.put(s.bits, sender, <<pre::bitstring, 1::1, post::bitstring>>)}
    end
  end
end
