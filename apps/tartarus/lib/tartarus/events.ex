defmodule Tartarus.Events do
  @moduledoc """
  Counters and a subscription API for everything that happens on the hosts of this node.

  Every host counts its own events in its own `:counters` array (`host_counts/1`) and this
  module keeps node-wide totals in another. Processes that want the events
  themselves subscribe; a node without subscribers pays only the counters.

  ## Events

  Each event is delivered to subscribers as `{:tartarus_event, event}` where `event` is a map
  with at least `:type`, `:host` (the host it happened on, as `{name, node}`) and `:time`
  (`Tartarus.Clock.system_time(:microsecond)`). The types and their extra keys:

  | type           | extra keys                                   | counted as        |
  |----------------|----------------------------------------------|-------------------|
  | `:created`     | `:agent`, `:module`                          | `:created`        |
  | `:arrival`     | `:agent`, `:from`, `:hop_us`, `:hops`        | `:arrivals`       |
  | `:departure`   | `:agent`, `:to`, `:bytes`, `:code_bytes`     | `:departures`, `:bytes`, `:code_bytes` |
  | `:move_failed` | `:agent`, `:to`, `:reason`                   | `:move_failed`    |
  | `:clone`       | `:agent`, `:clone`, `:to`                    | `:clones`         |
  | `:kill`        | `:agent`                                     | `:kills`          |
  | `:stopped`     | `:agent`, `:reason`                          | `:stopped`        |
  | `:crash`       | `:agent`, `:reason`, `:restarts`             | `:crashes`        |
  | `:removed`     | `:agent`, `:reason` (restart limit reached)  | `:removed`        |
  | `:message`     | `:agent`, `:bytes`, `:kind` (`:post`, `:request`, `:cast`), `:sender` (the sending process), `:message` (the message when at most 256 bytes, else nil) | `:messages`, `:message_bytes` |
  | `:refused`     | `:agent`, `:from`, `:reason`                 | `:refused`        |
  | `:dropped`     | `:service`, `:kind`                          | `:dropped`        |
  | `:broadcast`   | `:to`, `:messages`, `:bytes` (see `Tartarus.Broadcast`) | `:broadcasts`, `:broadcast_messages`, `:broadcast_bytes` |
  | `:broadcast_received` | `:from`, `:bytes`                     | `:broadcasts_received` |
  | `:signal`      | `:name`, `:strength`, `:span` (see `Tartarus.Signal`) | `:signals`  |
  | `:signal_relay` | `:name`, `:source`, `:to`, `:messages`, `:bytes` | `:signal_messages`, `:signal_bytes` |
  | `:journal_damaged` | `:path`, `:moved_to`, `:ranges`, `:unreadable_bytes`, `:records` | `:journal_damaged`, `:journal_unreadable_bytes` |
  | `:journal_refused` | `:agent`, `:reason` (a write the journal could not take) | `:journal_refused` |

  A `:journal_damaged` event comes once, when a host opens a journal it could not read whole
  (`Tartarus.start_host/2` with `data_dir:`): `:ranges` are the `{offset, length}` of the
  bytes it could not read (a torn tail, a damaged frame, junk), `:records` the records it
  did read and restored, `:moved_to` where the original file now is (kept, never deleted).

  A `:dropped` event is a message, cast or call that a platform process did not expect (from
  another node, well-formed or not) and dropped instead of crashing (`:host` is `nil` for the
  node-level services, the host's address for a host's own processes); `:service` names the
  process (e.g. `Tartarus.CodeCache`) and `:kind` is `:info`, `:cast` or `:call`. Per-service
  counts are in `dropped/0`. Each service logs at most one line per second about what it drops.

  Bytes are `:erlang.external_size/1` of what crosses a link (the envelope, shipped code,
  a posted message): what distributed Erlang would carry, also in virtual mode where nothing
  leaves the VM, so that emulations can compute traffic and energy.

  ## Example

      Tartarus.Events.subscribe()
      {:ok, _} = Tartarus.start_host(:a)
      Tartarus.Events.totals().arrivals
  """

  require Logger

  @counter_names [
    :created,
    :arrivals,
    :departures,
    :move_failed,
    :clones,
    :kills,
    :stopped,
    :crashes,
    :removed,
    :messages,
    :message_bytes,
    :bytes,
    :code_bytes,
    :refused,
    :dropped,
    :broadcasts,
    :broadcast_messages,
    :broadcast_bytes,
    :broadcasts_received,
    :signals,
    :signal_messages,
    :signal_bytes,
    :journal_damaged,
    :journal_unreadable_bytes,
    :journal_refused
  ]
  @index @counter_names |> Enum.with_index(1) |> Map.new()
  # {name, index} of every counter, in order (a list: read per host, often).
  @named Enum.with_index(@counter_names, 1)

  # Event types (the table above), counted node-wide per type; any other type counts as :other.
  @types [
    :created,
    :arrival,
    :departure,
    :move_failed,
    :clone,
    :kill,
    :stopped,
    :crash,
    :removed,
    :message,
    :refused,
    :dropped,
    :broadcast,
    :broadcast_received,
    :signal,
    :signal_relay,
    :journal_damaged,
    :journal_refused,
    :other
  ]
  @type_index @types |> Enum.with_index(1) |> Map.new()
  @typed Enum.with_index(@types, 1)

  @typedoc "The name of a counter; see the table in the moduledoc."
  @type counter :: atom()

  @typedoc "An event as delivered to subscribers."
  @type event :: %{
          required(:type) => atom(),
          required(:host) => term(),
          optional(atom()) => term()
        }

  @dropped_table Tartarus.Events.Dropped
  @log_interval_ms 1_000

  @doc false
  # Called by Tartarus.Application.start/2, in the application's own process: the table of
  # dropped-message counts lives as long as the application, whatever service restarts.
  def setup do
    :persistent_term.put(
      {__MODULE__, :counters},
      :counters.new(map_size(@index), [:write_concurrency])
    )

    :persistent_term.put(
      {__MODULE__, :types},
      :counters.new(map_size(@type_index), [:write_concurrency])
    )

    if :ets.whereis(@dropped_table) == :undefined do
      :ets.new(@dropped_table, [:named_table, :public, :set, write_concurrency: true])
    end

    :ok
  end

  @doc """
  How many unexpected messages each platform process dropped since the application started,
  by service (the process's registered name or role, e.g. `Tartarus.CodeCache`).

      iex> is_map(Tartarus.Events.dropped())
      true
  """
  @spec dropped() :: %{term() => non_neg_integer()}
  def dropped do
    case :ets.whereis(@dropped_table) do
      :undefined -> %{}
      _ -> Map.new(:ets.tab2list(@dropped_table), fn {service, n, _last} -> {service, n} end)
    end
  end

  @doc false
  # Drops `message` (of `kind` :info, :cast or :call) that `service` did not expect: counts
  # it (node-wide `:dropped` counter, per service, and in `host`'s counters when a host's
  # info map is given), tells subscribers, and logs at most one line per second per service.
  # Never raises.
  @spec drop(term(), :info | :cast | :call, term(), map() | nil) :: :ok
  def drop(service, kind, message, host \\ nil) do
    n = :ets.update_counter(@dropped_table, service, {2, 1}, {service, 0, -@log_interval_ms})
    # A rate of log lines, for whoever reads the log: the machine's time in either mode.
    now = Tartarus.Clock.machine_time(:millisecond)
    last = :ets.lookup_element(@dropped_table, service, 3)

    if now - last >= @log_interval_ms do
      :ets.update_element(@dropped_table, service, {3, now})

      Logger.warning(
        "#{inspect(service)} dropped an unexpected #{kind} (#{n} so far): " <>
          inspect(message, limit: 8, printable_limit: 64)
      )
    end

    ref = if is_map(host), do: host[:ref]
    emit(host, %{type: :dropped, host: ref, service: service, kind: kind}, dropped: 1)
  rescue
    _ -> :ok
  end

  @doc "The names of all counters."
  @spec counter_names() :: [counter()]
  def counter_names, do: @counter_names

  @doc """
  Subscribes the caller to every event of every host on this node. The subscription ends
  with `unsubscribe/0` or when the process exits. To watch another node, subscribe from a
  process started there (for instance with `:erpc.call/4`).

  With `budget: {n, ms}` the caller gets at most about `n` events in each window of `ms`
  milliseconds (of `Tartarus.Clock.monotonic_time/1`): the first ones of the window; the others are not sent at all (emitting them
  costs the emitter two atomic operations, not a message), and they are still counted in
  `type_totals/0` and the hosts' counters (`Tartarus.status/2`). For a watcher that shows a
  sample of the events and exact counts, without a message per event however busy the node is.

      iex> Tartarus.Events.subscribe(budget: {100, 250})
      :ok
      iex> Tartarus.Events.unsubscribe()
      :ok
  """
  @spec subscribe(keyword()) :: :ok
  def subscribe(opts \\ []) do
    value =
      case Keyword.get(opts, :budget) do
        nil ->
          nil

        {n, ms} when is_integer(n) and n > 0 and is_integer(ms) and ms > 0 ->
          ref = :atomics.new(2, signed: true)
          # The window now (monotonic time may be negative: windows only grow from here).
          :atomics.put(ref, 1, div(Tartarus.Clock.monotonic_time(:millisecond), ms))
          {:budget, ref, n, ms}

        other ->
          raise ArgumentError,
                "budget: expected {events, ms} (positive integers), got: #{inspect(other)}"
      end

    {:ok, _} = Registry.register(Tartarus.Events.Registry, :events, value)
    # Emitters look for subscribers only once somebody has subscribed (a persistent_term
    # flag: free to read, written once).
    unless :persistent_term.get({__MODULE__, :subscribed}, false),
      do: :persistent_term.put({__MODULE__, :subscribed}, true)

    :ok
  end

  @doc "Ends the caller's subscription."
  @spec unsubscribe() :: :ok
  def unsubscribe do
    Registry.unregister(Tartarus.Events.Registry, :events)
  end

  @doc """
  Node-wide totals of every counter since the application started.

      iex> Map.has_key?(Tartarus.Events.totals(), :arrivals)
      true
  """
  @spec totals() :: %{counter() => non_neg_integer()}
  def totals, do: read(counters(), @named)

  @doc """
  Node-wide counts of the events emitted since the application started, per event type (the
  table above; any other type under `:other`), whoever subscribed or not.

      iex> Map.has_key?(Tartarus.Events.type_totals(), :arrival)
      true
  """
  @spec type_totals() :: %{atom() => non_neg_integer()}
  def type_totals do
    read(:persistent_term.get({__MODULE__, :types}), @typed)
  end

  @doc false
  # Counts `amounts` (a keyword list of counter => increment) for `host` (a host's info map,
  # or nil) and node-wide, and hands the event to subscribers if there are any.
  @spec emit(map() | nil, map(), keyword()) :: :ok
  def emit(host, event, amounts) do
    ref = counters()

    Enum.each(amounts, fn {name, n} ->
      i = Map.fetch!(@index, name)
      :counters.add(ref, i, n)
      if host, do: :counters.add(host.counters, i, n)
    end)

    :counters.add(
      :persistent_term.get({__MODULE__, :types}),
      Map.get(@type_index, Map.get(event, :type), map_size(@type_index)),
      1
    )

    if :persistent_term.get({__MODULE__, :subscribed}, false) do
      case subscribers() do
        [] ->
          :ok

        subscribers ->
          time = Tartarus.Clock.system_time(:microsecond)
          msg = {:tartarus_event, Map.put_new(event, :time, time)}

          Enum.each(subscribers, fn
            {pid, nil} -> send(pid, msg)
            {pid, {:budget, ref, n, ms}} -> if within?(ref, n, ms), do: send(pid, msg)
            _ -> :ok
          end)
      end
    end

    :ok
  end

  # A budgeted subscriber's window: slot 1 holds the window's number, slot 2 the events sent
  # in it. The emitter that first sees a new window resets the count (a few emitters racing
  # there may let a few more through: "at most about n").
  defp within?(ref, n, ms) do
    w = div(Tartarus.Clock.monotonic_time(:millisecond), ms)

    case :atomics.get(ref, 1) do
      ^w ->
        :ok

      old when old < w ->
        if :atomics.compare_exchange(ref, 1, old, w) == :ok, do: :atomics.put(ref, 2, 0)

      _ ->
        :ok
    end

    :atomics.add_get(ref, 2, 1) <= n
  end

  @doc false
  # A `from` that gen_server can answer: a junk `{:"$gen_call", from, msg}` sent by hand may
  # carry anything, and a `{:reply, ...}` return on it crashes the server. Servers that reply
  # by return drop calls whose `from` fails this guard (a first handle_call clause).
  defguard is_from(from) when is_tuple(from) and tuple_size(from) == 2 and is_pid(elem(from, 0))

  @doc false
  # Answers a call whose `from` came with the message: a junk `{:"$gen_call", from, msg}` sent
  # by hand may carry a `from` that is no `{pid, tag}`, and gen_server's own reply would crash
  # the server on it. Use as `{:noreply, state}` after `reply(from, answer)`.
  @spec reply(term(), term()) :: :ok
  def reply({to, _tag} = from, answer) when is_pid(to) do
    GenServer.reply(from, answer)
    :ok
  catch
    _, _ -> :ok
  end

  def reply(_from, _answer), do: :ok

  # The registry restarts on its own (Tartarus.Application); meanwhile nobody is subscribed.
  defp subscribers do
    Registry.lookup(Tartarus.Events.Registry, :events)
  rescue
    ArgumentError -> []
  end

  @doc false
  # A fresh counter array for one host.
  def new_counters, do: :counters.new(map_size(@index), [:write_concurrency])

  @doc false
  # Per-host counts.
  @spec host_counts(map()) :: %{counter() => non_neg_integer()}
  def host_counts(%{counters: ref}), do: read(ref, @named)

  defp read(ref, named),
    do: :maps.from_list(for {name, i} <- named, do: {name, :counters.get(ref, i)})

  defp counters, do: :persistent_term.get({__MODULE__, :counters})
end
