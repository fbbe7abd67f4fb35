defmodule TartarusLats.BeaconPlugin do
  @moduledoc """
  The BLE receiver of a LATS node, as a `Tartarus.Plugin` (simulated).

  A node's database agent reaches its receiver only through the platform's
  plugin channel: `Tartarus.Agent.read(:beacon, {:scan, t})` returns what the
  receiver heard in second `t` as `%{tag => rssi}` (tags not heard are
  absent). Here the radio is simulated: the emulation driver
  (`TartarusLats.Deployment`) draws every node's readings from the world
  each second and writes them into the receiver (`Tartarus.write_plugin/3`
  with `{:readings, t, readings}`), or the receiver plays a script. The
  real receiver (an HM-10 on a tty or the Pi's UART, its `AT+DISI?` output
  parsed by `TartarusLats.HM10`) answers the same `{:scan, t}` read:
  `TartarusLats.HM10.Receiver`, see docs/devices.md. Recorded serial output is replayed into this receiver by
  the driver (`TartarusLats.Deployment`, option `:replay`).

  Options:

    * `:node` - the node (zone) this receiver stands in (required);
    * `:script` - `%{second => %{tag => rssi}}` for tests (seconds absent
      from the script hear nothing). Without a script the receiver hears
      only what is written into it.

  Reads: `{:scan, t}` (the readings of second `t`: those written for `t`,
  else the script's, else nothing), `:last` (the last scan, `{t, readings}`
  or `nil`). Writes: `{:readings, t, readings}` gives the readings of second
  `t` (they take precedence over the script): the emulation driver, a test
  or a hardware bridge. Readings of earlier seconds not scanned are
  dropped at the next scan. A reading that is not `{uuid, major, minor} =>
  rssi` (32 lowercase hex digits, 16-bit major and minor, an integer RSSI
  the HM-10 can report) is refused: dropped and counted (read `:refused`,
  and `describe/1`); the valid readings of the same write are kept.
  """
  @behaviour Tartarus.Plugin

  @schema [
    node: [type: :any, required: true, doc: "the node this receiver stands in"],
    script: [type: :any, default: %{}, doc: "`%{second => %{tag => rssi}}`"]
  ]

  @impl true
  def init(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusLats.BeaconPlugin"),
         :ok <- check(opts) do
      {:ok, %{node: opts[:node], script: opts[:script], injected: %{}, last: nil, refused: 0}}
    end
  end

  defp check(opts) do
    cond do
      opts[:node] == nil ->
        {:error,
         "invalid options given to TartarusLats.BeaconPlugin for key :node: expected the node this receiver stands in, got: nil"}

      not is_map(opts[:script]) ->
        {:error,
         "invalid options given to TartarusLats.BeaconPlugin for key :script: expected a map of second => readings, got: #{inspect(opts[:script])}"}

      true ->
        :ok
    end
  end

  @impl true
  def describe(s) do
    %{
      kind: :ble_receiver,
      node: s.node,
      reads: [:scan, :last, :refused],
      writes: [:readings],
      refused: s.refused
    }
  end

  @impl true
  def read({:scan, t}, s) when is_integer(t) do
    {readings, injected} = Map.pop(s.injected, t)
    readings = readings || Map.get(s.script, t, %{})
    injected = Map.reject(injected, fn {second, _} -> second < t end)
    {:ok, readings, %{s | injected: injected, last: {t, readings}}}
  end

  def read(:last, s), do: {:ok, s.last, s}
  def read(:refused, s), do: {:ok, s.refused, s}
  def read(arg, s), do: {:error, {:bad_argument, arg}, s}

  @impl true
  def write({:readings, t, readings}, s) when is_integer(t) and is_map(readings) do
    {good, bad} = Enum.split_with(readings, &valid_reading?/1)
    s = %{s | refused: s.refused + length(bad)}
    {:ok, %{s | injected: Map.put(s.injected, t, Map.new(good))}}
  end

  def write(arg, s), do: {:error, {:bad_argument, arg}, s}

  @doc """
  Whether `{tag, rssi}` is a reading LATS takes: a tag `{uuid, major, minor}` as
  `TartarusLats.Beacon.tag_id/1` makes it and an RSSI `TartarusLats.IBeacon.valid_rssi?/1`
  accepts.

      iex> TartarusLats.BeaconPlugin.valid_reading?({{"12121212b64445208f0c720eaf059935", 1, 2}, -70})
      true
      iex> TartarusLats.BeaconPlugin.valid_reading?({{"nope", 1, 2}, -70})
      false
      iex> TartarusLats.BeaconPlugin.valid_reading?({{"12121212b64445208f0c720eaf059935", 1, 2}, :loud})
      false
  """
  @spec valid_reading?(term()) :: boolean()
  def valid_reading?({{uuid, major, minor}, rssi})
      when is_binary(uuid) and byte_size(uuid) == 32 and is_integer(major) and major in 0..65535 and
             is_integer(minor) and minor in 0..65535 do
    TartarusLats.IBeacon.valid_rssi?(rssi) and
      match?({:ok, _}, Base.decode16(uuid, case: :lower))
  end

  def valid_reading?(_), do: false
end
