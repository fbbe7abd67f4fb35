defmodule Tartarus.Plugin.Serial do
  @schema [
    device: [type: :string, required: true, doc: "the device's path, e.g. `/dev/ttyUSB0`"],
    speed: [type: :pos_integer, default: 9600, doc: "the line's speed in baud"],
    decoder: [
      type: :atom,
      default: Tartarus.Plugin.Serial.Lines,
      doc: "a `Tartarus.Plugin.Serial.Decoder`"
    ],
    decoder_opts: [type: :keyword, default: [], doc: "the decoder's options"],
    transport: [
      type: :atom,
      default: Tartarus.Plugin.Serial.Tty,
      doc: "a `Tartarus.Plugin.Serial.Transport`"
    ],
    transport_opts: [type: :keyword, default: [], doc: "the transport's own options"],
    backoff_ms: [
      type: {:custom, &__MODULE__.backoff?/1},
      expected: "{first, longest} positive integers with first <= longest",
      default: {100, 5000},
      doc: "the first and the longest delay between attempts to open the device"
    ],
    on_open: [
      type: :string,
      default: "",
      doc: "bytes written each time the device opens (e.g. AT set-up commands)"
    ],
    max_backlog: [
      type: :pos_integer,
      default: 1000,
      doc:
        "messages waiting in the plugin's mailbox beyond which the device's data is dropped (and counted) instead of decoded"
    ],
    poll: [
      type: {:or, [{:in, [nil]}, {:tuple, [:string, :pos_integer]}]},
      expected: "nil or {bytes, interval_ms}",
      default: nil,
      doc:
        "`{bytes, interval_ms}`: bytes written every `interval_ms` while open (e.g. a scan command)"
    ]
  ]

  @moduledoc """
  A serial device as a `Tartarus.Plugin`: a transport that opens the line and reopens it
  when the device comes back, and a decoder that turns its bytes into events and readings.

      Tartarus.attach_plugin(:pi1, :console,
        {Tartarus.Plugin.Serial, device: "/dev/ttyUSB0", speed: 115_200})

      # a BLE module that scans when asked, with an application's decoder
      Tartarus.attach_plugin(:pi1, :beacon,
        {Tartarus.Plugin.Serial,
         device: "/dev/ttyAMA0", decoder: MyApp.ScanDecoder, poll: {"AT+DISI?", 1000}})

  The transport (`Tartarus.Plugin.Serial.Transport`) is `Tartarus.Plugin.Serial.Tty` by
  default (any Linux tty, no dependency); the firmware brings one over `Circuits.UART`. The
  decoder (`Tartarus.Plugin.Serial.Decoder`) is `Tartarus.Plugin.Serial.Lines` by default.

  ## Unplugged, replugged

  Attaching never fails because the device is absent: the plugin tries to open it, and
  while it cannot (or after the device went away) it tries again after a delay that starts
  at the first `:backoff_ms` bound, doubles at each failure up to the second, and starts
  over once the device is open. When the device goes away the decoder forgets the frame it
  was in the middle of (`reset/1`), so the bytes of a half-received record never join the
  bytes of the next device.

  ## A device that floods the line

  The device's data arrives as messages in the plugin's mailbox. When more than
  `:max_backlog` messages wait there (a faulty device, or a line faster than the decoder),
  each chunk of data taken from the mailbox is dropped without being decoded, and counted
  (`:dropped` in `:status` and in the plugin's description: `%{chunks: n, bytes: n}`),
  until the backlog is under the limit again; the device's "opened" and "closed" are
  never dropped. Dropping costs next to nothing, so the plugin drains its mailbox faster
  than a device can fill it: the backlog stays near the limit and a read (`:status`, a
  host's `Tartarus.status/1`) waits for at most that many cheap drops.

  ## Events, reads, writes

  Subscribers get the decoder's events and `{:serial, :up}` (opened) and
  `{:serial, :down, reason}` (lost or closed). Reads: `:status` (a map: `:status`
  `:open | :opening | :closed`, `:device`, `:opens`, `:bytes` received and decoded,
  `:dropped` (see above), `:last_error`);
  anything else goes to the decoder's `read/2`. Writes: `{:send, iodata}` writes bytes to
  the device (`{:error, :closed}` unless it is open); anything else is
  `{:error, {:bad_argument, arg}}`.

  Options:

  #{Tartarus.Options.docs(@schema)}
  """
  @behaviour Tartarus.Plugin

  @doc false
  def backoff?({a, b}) when is_integer(a) and is_integer(b), do: a > 0 and a <= b
  def backoff?(_), do: false

  @doc """
  Checks `opts` as `init/1` does, without opening the device (what a node's configuration
  check calls through `Tartarus.Plugin.Shorthand`): `:ok` or `{:error, line}`.

      iex> Tartarus.Plugin.Serial.check(device: "/dev/ttyUSB0", speed: 115_200)
      :ok
      iex> Tartarus.Plugin.Serial.check(device: "/dev/ttyUSB0", speed: "fast")
      {:error, "invalid options given to Tartarus.Plugin.Serial for key :speed: expected a positive integer, got: \\"fast\\""}
  """
  @spec check(keyword()) :: :ok | {:error, String.t()}
  def check(opts) do
    with {:ok, _} <- validated(opts), do: :ok
  end

  defp validated(opts) do
    with {:ok, o} <- Tartarus.Options.validate(opts, @schema, "Tartarus.Plugin.Serial"),
         :ok <- implements(o[:decoder], Tartarus.Plugin.Serial.Decoder, :decoder),
         :ok <- implements(o[:transport], Tartarus.Plugin.Serial.Transport, :transport) do
      {:ok, o}
    end
  end

  @impl true
  def init(opts) do
    with {:ok, o} <- validated(opts),
         {:ok, decoder_state} <- o[:decoder].init(o[:decoder_opts]) do
      send(self(), {__MODULE__, :connect})

      poll =
        case o[:poll] do
          {_bytes, interval} -> poll(Tartarus.Clock.monotonic_time(:millisecond), interval)
          nil -> nil
        end

      {:ok,
       %{
         o: Map.new(o),
         poll: poll,
         conn: nil,
         status: :closed,
         decoder: decoder_state,
         delay: elem(o[:backoff_ms], 0),
         opens: 0,
         bytes: 0,
         dropped: %{chunks: 0, bytes: 0},
         last_error: nil
       }}
    end
  end

  defp implements(module, behaviour, key) do
    callbacks =
      behaviour.behaviour_info(:callbacks) -- behaviour.behaviour_info(:optional_callbacks)

    if Code.ensure_loaded?(module) and
         Enum.all?(callbacks, fn {f, a} -> function_exported?(module, f, a) end) do
      :ok
    else
      {:error,
       "invalid options given to Tartarus.Plugin.Serial for key :#{key}: expected a module implementing #{inspect(behaviour)}, got: #{inspect(module)}"}
    end
  end

  @impl true
  def describe(s) do
    decoder = s.o.decoder

    own = %{
      kind: :serial,
      device: s.o.device,
      status: s.status,
      dropped: s.dropped,
      reads: [:status],
      writes: [:send],
      events: [:serial]
    }

    if function_exported?(decoder, :describe, 1) do
      d = decoder.describe(s.decoder)

      Map.merge(own, d, fn
        k, a, b when k in [:reads, :writes, :events] and is_list(b) -> Enum.uniq(a ++ b)
        _k, _a, b -> b
      end)
    else
      own
    end
  end

  @impl true
  def read(:status, s) do
    {:ok,
     %{
       status: s.status,
       device: s.o.device,
       opens: s.opens,
       bytes: s.bytes,
       dropped: s.dropped,
       last_error: s.last_error
     }, s}
  end

  def read(args, s) do
    decoder = s.o.decoder

    if function_exported?(decoder, :read, 2) do
      case decoder.read(args, s.decoder) do
        {:ok, value, d} -> {:ok, value, %{s | decoder: d}}
        {:error, reason, d} -> {:error, reason, %{s | decoder: d}}
      end
    else
      {:error, {:bad_argument, args}, s}
    end
  end

  @impl true
  def write({:send, data}, %{status: :open} = s) do
    case s.o.transport.write(s.conn, data) do
      :ok -> {:ok, s}
      {:error, reason} -> {:error, reason, s}
    end
  end

  def write({:send, _data}, s), do: {:error, :closed, s}
  def write(arg, s), do: {:error, {:bad_argument, arg}, s}

  @impl true
  def handle_info({__MODULE__, :connect}, %{conn: nil} = s) do
    case s.o.transport.open(s.o.device, [speed: s.o.speed] ++ s.o.transport_opts) do
      {:ok, conn} -> {:events, [], %{s | conn: conn, status: :opening}}
      {:error, reason} -> {:events, [], retry(%{s | last_error: reason})}
    end
  end

  # Every poll interval, open or not (only an open device is written to).
  def handle_info({__MODULE__, :poll, at}, %{poll: at} = s) do
    {bytes, interval} = s.o.poll
    if s.status == :open, do: s.o.transport.write(s.conn, bytes)
    {:events, [], %{s | poll: poll(at, interval)}}
  end

  def handle_info({__MODULE__, :poll, _stale}, s), do: {:events, [], s}

  def handle_info({__MODULE__, _}, s), do: {:events, [], s}

  def handle_info(msg, %{conn: conn} = s) when conn != nil do
    case s.o.transport.message(msg, conn) do
      :ignore -> {:events, [], s}
      {items, conn} -> Enum.reduce(shed(items, s), {:events, [], %{s | conn: conn}}, &item/2)
    end
  end

  def handle_info(_msg, s), do: {:events, [], s}

  # Over the backlog limit, data items become drops (counted, not decoded).
  defp shed(items, s) do
    {:message_queue_len, waiting} = Process.info(self(), :message_queue_len)

    if waiting > s.o.max_backlog,
      do:
        Enum.map(items, fn
          {:data, bytes} -> {:drop, bytes}
          other -> other
        end),
      else: items
  end

  defp item({:drop, bytes}, {:events, events, s}) do
    dropped = %{chunks: s.dropped.chunks + 1, bytes: s.dropped.bytes + byte_size(bytes)}
    {:events, events, %{s | dropped: dropped}}
  end

  # The device's state changes and data, in order; events accumulate in order.
  defp item(:opened, {:events, events, s}) do
    if s.o.on_open != "", do: s.o.transport.write(s.conn, s.o.on_open)
    s = %{s | status: :open, opens: s.opens + 1, delay: elem(s.o.backoff_ms, 0)}
    {:events, events ++ [{:serial, :up}], s}
  end

  defp item({:data, bytes}, {:events, events, s}) do
    {decoded, d} = s.o.decoder.feed(bytes, s.decoder)
    {:events, events ++ decoded, %{s | decoder: d, bytes: s.bytes + byte_size(bytes)}}
  end

  defp item({:closed, reason}, {:events, events, %{conn: nil} = s}) do
    {:events, events, %{s | last_error: reason}}
  end

  defp item({:closed, reason}, {:events, events, s}) do
    {dropped, d} = s.o.decoder.reset(s.decoder)
    was_open = s.status == :open
    s = retry(%{s | conn: nil, decoder: d, last_error: reason})
    down = if was_open, do: [{:serial, :down, reason}], else: []
    {:events, events ++ dropped ++ down, s}
  end

  # The next poll, one interval after the one before (no drift, as with
  # :timer.send_interval/2), in Tartarus.Clock's time: its due time tells it from any other.
  defp poll(at, interval) do
    at = at + interval
    Tartarus.Clock.send_after(self(), {__MODULE__, :poll, at}, at, abs: true)
    at
  end

  defp retry(s) do
    Tartarus.Clock.send_after(self(), {__MODULE__, :connect}, s.delay)
    %{s | status: :closed, conn: nil, delay: min(s.delay * 2, elem(s.o.backoff_ms, 1))}
  end
end
