defmodule Tartarus.Events do
  @moduledoc """
  Counters and a subscription API for everything that happens on the hosts of this node.

  Every host counts its own events in its ledger (cheap `:ets.update_counter/4` calls) and
  this module keeps node-wide totals in a `:counters` array. Processes that want the events
  themselves subscribe; a node without subscribers pays only the counters.

  ## Events

  Each event is delivered to subscribers as `{:tartarus_event, event}` where `event` is a map
  with at least `:type`, `:host` (the host it happened on, as `{name, node}`) and `:time`
  (`System.system_time(:microsecond)`). The types and their extra keys:

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
  | `:message`     | `:agent`, `:bytes`                           | `:messages`, `:message_bytes` |
  | `:refused`     | `:agent`, `:from`, `:reason`                 | `:refused`        |
  | `:broadcast`   | `:to`, `:messages`, `:bytes` (see `Tartarus.Broadcast`) | `:broadcasts`, `:broadcast_messages`, `:broadcast_bytes` |
  | `:broadcast_received` | `:from`, `:bytes`                     | `:broadcasts_received` |
  | `:signal`      | `:name`, `:strength`, `:span` (see `Tartarus.Signal`) | `:signals`  |
  | `:signal_relay` | `:name`, `:source`, `:to`, `:messages`, `:bytes` | `:signal_messages`, `:signal_bytes` |

  Bytes are `:erlang.external_size/1` of what crosses a link (the envelope, shipped code,
  a posted message): what distributed Erlang would carry, also in virtual mode where nothing
  leaves the VM, so that emulations can compute traffic and energy.

  ## Example

      Tartarus.Events.subscribe()
      {:ok, _} = Tartarus.start_host(:a)
      Tartarus.Events.totals().arrivals
  """

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
    :broadcasts,
    :broadcast_messages,
    :broadcast_bytes,
    :broadcasts_received,
    :signals,
    :signal_messages,
    :signal_bytes
  ]
  @index @counter_names |> Enum.with_index(1) |> Map.new()

  @typedoc "The name of a counter; see the table in the moduledoc."
  @type counter :: atom()

  @typedoc "An event as delivered to subscribers."
  @type event :: %{
          required(:type) => atom(),
          required(:host) => term(),
          optional(atom()) => term()
        }

  @doc false
  def setup do
    :persistent_term.put(
      {__MODULE__, :counters},
      :counters.new(map_size(@index), [:write_concurrency])
    )
  end

  @doc "The names of all counters."
  @spec counter_names() :: [counter()]
  def counter_names, do: @counter_names

  @doc """
  Subscribes the caller to every event of every host on this node. The subscription ends
  with `unsubscribe/0` or when the process exits. To watch another node, subscribe from a
  process started there (for instance with `:erpc.call/4`).
  """
  @spec subscribe() :: :ok
  def subscribe do
    {:ok, _} = Registry.register(Tartarus.Events.Registry, :events, nil)
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
  def totals do
    ref = counters()
    Map.new(@index, fn {name, i} -> {name, :counters.get(ref, i)} end)
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

    if :persistent_term.get({__MODULE__, :subscribed}, false) do
      case Registry.lookup(Tartarus.Events.Registry, :events) do
        [] ->
          :ok

        subscribers ->
          event = Map.put_new(event, :time, System.system_time(:microsecond))
          Enum.each(subscribers, fn {pid, _} -> send(pid, {:tartarus_event, event}) end)
      end
    end

    :ok
  end

  @doc false
  # A fresh counter array for one host.
  def new_counters, do: :counters.new(map_size(@index), [:write_concurrency])

  @doc false
  # Per-host counts.
  @spec host_counts(map()) :: %{counter() => non_neg_integer()}
  def host_counts(%{counters: ref}) do
    Map.new(@index, fn {name, i} -> {name, :counters.get(ref, i)} end)
  end

  defp counters, do: :persistent_term.get({__MODULE__, :counters})
end
