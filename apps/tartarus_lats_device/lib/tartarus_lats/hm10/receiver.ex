defmodule TartarusLats.HM10.Receiver do
  @moduledoc """
  A real HM-10 on a serial line, for the node's database agent: the
  `Tartarus.Plugin.Serial.Decoder` that turns the HM-10's scan output (parsed by
  `TartarusLats.HM10`) into the reads of `TartarusLats.BeaconPlugin`.

  Attach it as the node's `:beacon` plugin, on a plain Linux host (any tty, through
  `Tartarus.Plugin.Serial.Tty`) or on a Pi (the firmware's `Circuits.UART` transport):

      Tartarus.attach_plugin(host, :beacon, TartarusLats.HM10.Receiver.plugin("/dev/ttyUSB0"))

  The serial plugin writes `AT+DISI?` every second (one scan each), reassembles the
  records however the line chunks them and reopens the device when it comes back.

  ## Reads

    * `{:scan, t}` - what the receiver heard in the scans completed since the previous
      `{:scan, _}` read, as `%{tag => rssi}` (a tag heard twice keeps its strongest
      reading), the same shape as the simulated receiver's; `t` only labels the answer
      (`:last`), since a real receiver hears in wall time. A scan cut by the device going
      away is dropped, not half-counted.
    * `:last` - `{t, readings}` of the last `{:scan, t}` read, or `nil`;
    * `:counts` - what arrived: `:scans`, `:beacons`, `:other_devices`, `:bad_records`,
      `:garbage_bytes`, `:cut_scans` (scans cut by the device going away, or by a new scan
      starting before the last one ended), `:dropped_readings` (see below).

  ## Bounded

  A scan that never ends (a device that never prints `OK+DISCE`, or prints records
  forever) must not grow the plugin without bound: an unfinished scan keeps at most
  `:max_tags` tags (option, default #{200}); a reading of a further tag is dropped and
  counted (`:dropped_readings`, in `:counts` and in the plugin's description), while the
  tags already in the scan keep their strongest reading. At most #{60} completed scans wait
  for a read (the oldest are dropped). So the decoder's state is bounded by
  `max_tags x 61` readings and the parser's 1 KiB buffer, whatever the device prints.

  ## Events

  Subscribers receive the parser's events as they complete (`:scan_started`,
  `{:beacon, beacon, mac}`, `{:other_device, mac, rssi}`, `{:bad_record, raw, reason}`,
  `{:garbage, bytes}`, `:scan_ended`), then `{:scan_done, readings}` for every completed
  scan, and `{:scan_cut, readings_so_far}` when the device went away in a scan.

      iex> alias TartarusLats.{Beacon, HM10}
      iex> alias TartarusLats.HM10.Receiver
      iex> b = %Beacon{uuid: "74278bdab64445208f0c720eaf059935", major: 1, minor: 2, tx_power: -59, rssi: -61}
      iex> {:ok, r} = Receiver.init([])
      iex> {_events, r} = Receiver.feed("noise" <> HM10.encode_scan([b]), r)
      iex> {:ok, readings, r} = Receiver.read({:scan, 7}, r)
      iex> readings
      %{{"74278bdab64445208f0c720eaf059935", 1, 2} => -61}
      iex> Receiver.read({:scan, 8}, r) |> elem(1)
      %{}
  """
  @behaviour Tartarus.Plugin.Serial.Decoder

  alias TartarusLats.HM10

  # Scans kept while nobody reads them (beyond that the oldest are dropped).
  @max_pending 60
  @max_tags 200

  @doc """
  The plugin spec of an HM-10 receiver on `device`: `Tartarus.Plugin.Serial` with this
  decoder, `AT+DISI?` every `poll_ms` (default 1000) and `opts` passed on to the serial
  plugin (e.g. `speed:`, `backoff_ms:`, `transport:`).
  """
  @spec plugin(String.t(), keyword()) :: {module(), keyword()}
  def plugin(device, opts \\ []) do
    {poll_ms, opts} = Keyword.pop(opts, :poll_ms, 1000)

    {Tartarus.Plugin.Serial,
     [device: device, decoder: __MODULE__, poll: {"AT+DISI?", poll_ms}] ++ opts}
  end

  @impl true
  def init(opts) do
    case Keyword.get(opts, :max_tags, @max_tags) do
      max when is_integer(max) and max > 0 ->
        {:ok, new(max)}

      other ->
        {:error,
         "invalid options given to TartarusLats.HM10.Receiver for key :max_tags: expected a positive integer, got: #{inspect(other)}"}
    end
  end

  defp new(max_tags) do
    %{
      max_tags: max_tags,
      parser: HM10.new(),
      scan: nil,
      pending: [],
      last: nil,
      counts: %{
        scans: 0,
        beacons: 0,
        other_devices: 0,
        bad_records: 0,
        garbage_bytes: 0,
        cut_scans: 0,
        dropped_readings: 0
      }
    }
  end

  @impl true
  def feed(bytes, r) do
    {parser, events} = HM10.feed(r.parser, bytes)
    {out, r} = Enum.reduce(events, {[], %{r | parser: parser}}, &take/2)
    {Enum.reverse(out), r}
  end

  # A scan that starts before the last one ended: the unfinished one is cut.
  defp take(:scan_started = e, {out, %{scan: nil} = r}), do: {[e | out], %{r | scan: %{}}}

  defp take(:scan_started = e, {out, r}),
    do: {[e, {:scan_cut, r.scan} | out], %{r | scan: %{}} |> count(:cut_scans, 1)}

  defp take({:beacon, b, _mac} = e, {out, r}) do
    tag = TartarusLats.Beacon.tag_id(b)
    scan = r.scan || %{}
    r = count(r, :beacons, 1)

    cond do
      is_map_key(scan, tag) ->
        {[e | out], %{r | scan: Map.update!(scan, tag, &max(&1, b.rssi))}}

      map_size(scan) < r.max_tags ->
        {[e | out], %{r | scan: Map.put(scan, tag, b.rssi)}}

      true ->
        {[e | out], count(r, :dropped_readings, 1)}
    end
  end

  defp take(:scan_ended = e, {out, r}) do
    scan = r.scan || %{}
    pending = Enum.take([scan | r.pending], @max_pending)
    {[{:scan_done, scan}, e | out], %{r | scan: nil, pending: pending} |> count(:scans, 1)}
  end

  defp take({:other_device, _, _} = e, {out, r}), do: {[e | out], count(r, :other_devices, 1)}
  defp take({:bad_record, _, _} = e, {out, r}), do: {[e | out], count(r, :bad_records, 1)}

  defp take({:garbage, bytes} = e, {out, r}),
    do: {[e | out], count(r, :garbage_bytes, byte_size(bytes))}

  defp count(r, key, n), do: %{r | counts: Map.update!(r.counts, key, &(&1 + n))}

  @impl true
  def reset(r) do
    cut = if r.scan, do: [{:scan_cut, r.scan}], else: []
    r = %{r | parser: HM10.new(), scan: nil}
    {cut, if(cut == [], do: r, else: count(r, :cut_scans, 1))}
  end

  @impl true
  def read({:scan, t}, r) when is_integer(t) do
    readings =
      r.pending
      |> Enum.reverse()
      |> Enum.reduce(%{}, fn scan, acc -> Map.merge(acc, scan, fn _, a, b -> max(a, b) end) end)

    {:ok, readings, %{r | pending: [], last: {t, readings}}}
  end

  def read(:last, r), do: {:ok, r.last, r}
  def read(:counts, r), do: {:ok, r.counts, r}
  def read(arg, r), do: {:error, {:bad_argument, arg}, r}

  @impl true
  def describe(r) do
    %{
      kind: :ble_receiver,
      chip: :hm10,
      reads: [:scan, :last, :counts],
      events: [:scan_started, :beacon, :scan_ended, :scan_done, :scan_cut, :garbage],
      counts: r.counts
    }
  end
end
