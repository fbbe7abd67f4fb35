defmodule TartarusLats.HM10 do
  @moduledoc """
  The HM-10's discovery output, as it arrives on a node's serial line: a streaming parser
  (and the encoder the simulator uses to record it).

  A LATS node asks its HM-10 (in central role, `AT+ROLE1`, `AT+IMME1`) to scan for iBeacons
  with `AT+DISI?`. The module answers in plain ASCII, without line breaks on most firmware
  (some add `\\r\\n`, which is accepted anywhere between records):

      OK+DISIS                                                      the scan starts
      OK+DISC:4C000215:74278BDAB64445208F0C720EAF059935:04D2045705:9CBA6D9A5A3A:-061
      OK+DISCE                                                      the scan ended

  Each `OK+DISC:` record has five colon-separated fields of fixed width: the factory id
  (8 hex digits; `4C000215` for an iBeacon: Apple's company id and the iBeacon type), the
  proximity UUID (32 hex digits), major (4), minor (4) and measured power at 1 m (2, two's
  complement), the device's MAC (12 hex digits) and the RSSI (a sign and 3 digits, dBm).
  A device that is not an iBeacon reports zeros in the first fields and is passed on as
  `{:other_device, mac, rssi}`.

  `feed/2` takes bytes as they come (any chunking: a record may be split anywhere) and
  returns the events completed so far. It never raises: bytes that are not part of a record
  are skipped and reported as `{:garbage, bytes}`, a record with a bad field as
  `{:bad_record, raw, reason}`; the parser then looks for the next `OK+`. At most
  #{1024} bytes are buffered while waiting for the rest of a record.

      iex> alias TartarusLats.{Beacon, HM10}
      iex> b = %Beacon{uuid: "74278bdab64445208f0c720eaf059935", major: 1234, minor: 1111, tx_power: -59, rssi: -61}
      iex> serial = HM10.encode_scan([b])
      iex> {p, events} = HM10.feed(HM10.new(), binary_part(serial, 0, 30))
      iex> events
      [:scan_started]
      iex> {_p, events} = HM10.feed(p, binary_part(serial, 30, byte_size(serial) - 30))
      iex> events
      [{:beacon, b, "000000000000"}, :scan_ended]
      iex> HM10.readings(events)
      %{{"74278bdab64445208f0c720eaf059935", 1234, 1111} => -61}
  """

  alias TartarusLats.{Beacon, IBeacon}

  @ibeacon "4C000215"
  @max_buffer 1024
  # "OK+DISC:" + 8 + ":" + 32 + ":" + 10 + ":" + 12 + ":" + 4
  @record_size 8 + 8 + 1 + 32 + 1 + 10 + 1 + 12 + 1 + 4

  @typedoc "The parser's state: bytes received and not yet consumed."
  @opaque t :: binary()

  @typedoc "What `feed/2` reports."
  @type event ::
          :scan_started
          | :scan_ended
          | {:beacon, Beacon.t(), mac :: String.t()}
          | {:other_device, mac :: String.t(), rssi :: integer()}
          | {:bad_record, raw :: binary(), reason :: atom()}
          | {:garbage, binary()}

  @doc "A parser that has received nothing."
  @spec new() :: t()
  def new, do: <<>>

  @doc """
  Feeds bytes received on the serial line; returns the parser and the events completed,
  in order.

      iex> {_, events} = TartarusLats.HM10.feed(TartarusLats.HM10.new(), "\\r\\nxxOK+DISIS\\r\\nOK+DISCE")
      iex> events
      [{:garbage, "xx"}, :scan_started, :scan_ended]
  """
  @spec feed(t(), binary()) :: {t(), [event()]}
  def feed(buffer, bytes) when is_binary(buffer) and is_binary(bytes) do
    {rest, events} = parse(buffer <> bytes, [])

    if byte_size(rest) > @max_buffer do
      {<<>>, Enum.reverse([{:garbage, rest} | events])}
    else
      {rest, Enum.reverse(events)}
    end
  end

  @doc """
  Parses a whole capture at once (what is left unfinished at its end is reported as
  garbage).

      iex> TartarusLats.HM10.parse_all("OK+DISISOK+DISC:")
      [:scan_started, {:garbage, "OK+DISC:"}]
  """
  @spec parse_all(binary()) :: [event()]
  def parse_all(bytes) do
    {rest, events} = feed(new(), bytes)
    if rest == <<>>, do: events, else: events ++ [{:garbage, rest}]
  end

  # Skip line breaks between records; recognise the three tokens; wait for more input when
  # what is buffered could still become one.
  defp parse(<<c, rest::binary>>, acc) when c in [?\r, ?\n], do: parse(rest, acc)
  defp parse(<<"OK+DISIS", rest::binary>>, acc), do: parse(rest, [:scan_started | acc])
  defp parse(<<"OK+DISCE", rest::binary>>, acc), do: parse(rest, [:scan_ended | acc])

  defp parse(<<"OK+DISC:", _::binary>> = bin, acc) when byte_size(bin) < @record_size,
    do: {bin, acc}

  defp parse(<<"OK+DISC:", _::binary>> = bin, acc) do
    <<raw::binary-size(@record_size), rest::binary>> = bin

    case record(raw) do
      {:bad_record, _, reason} ->
        # A short or damaged record: it ends where the next "OK+" starts, if that is within
        # its width, so the record after it is not lost.
        case :binary.match(raw, "OK+", scope: {1, @record_size - 1}) do
          {pos, _} ->
            {bad, rest} = :erlang.split_binary(bin, pos)
            parse(rest, [{:bad_record, bad, reason} | acc])

          :nomatch ->
            parse(rest, [{:bad_record, raw, reason} | acc])
        end

      event ->
        parse(rest, [event | acc])
    end
  end

  defp parse(<<>>, acc), do: {<<>>, acc}

  defp parse(bin, acc) do
    if prefix_of_token?(bin) do
      {bin, acc}
    else
      # Garbage up to the next "OK+" (or to a tail that may begin one).
      {junk, rest} = split_at_next_token(bin)
      parse(rest, [{:garbage, junk} | acc])
    end
  end

  @tokens ["OK+DISIS", "OK+DISCE", "OK+DISC:"]

  defp prefix_of_token?(bin),
    do: byte_size(bin) < 8 and Enum.any?(@tokens, &String.starts_with?(&1, bin))

  defp split_at_next_token(bin) do
    case :binary.match(bin, "OK+", scope: {1, byte_size(bin) - 1}) do
      {pos, _} ->
        :erlang.split_binary(bin, pos)

      :nomatch ->
        # Keep a tail that could be the start of "OK+" split by the chunking.
        keep = Enum.find([2, 1], 0, &(byte_size(bin) > &1 and tail_starts_token?(bin, &1)))
        :erlang.split_binary(bin, byte_size(bin) - keep)
    end
  end

  defp tail_starts_token?(bin, n),
    do: String.starts_with?("OK+", binary_part(bin, byte_size(bin) - n, n))

  defp record(
         <<"OK+DISC:", factory::binary-8, ?:, uuid::binary-32, ?:, major::binary-4,
           minor::binary-4, power::binary-2, ?:, mac::binary-12, ?:, sign, rssi::binary-3>> = raw
       ) do
    with {:ok, factory} <- hex(factory, :factory),
         {:ok, uuid_bytes} <- hex(uuid, :uuid),
         {:ok, <<major::16>>} <- hex(major, :major),
         {:ok, <<minor::16>>} <- hex(minor, :minor),
         {:ok, <<power::signed-8>>} <- hex(power, :power),
         {:ok, _} <- hex(mac, :mac),
         {:ok, rssi} <- rssi(sign, rssi) do
      if Base.encode16(factory) == @ibeacon do
        beacon = %Beacon{
          uuid: Base.encode16(uuid_bytes, case: :lower),
          major: major,
          minor: minor,
          tx_power: power,
          rssi: rssi
        }

        {:beacon, beacon, String.upcase(mac)}
      else
        {:other_device, String.upcase(mac), rssi}
      end
    else
      {:error, reason} -> {:bad_record, raw, reason}
    end
  end

  defp record(raw), do: {:bad_record, raw, :separators}

  defp hex(text, field) do
    case Base.decode16(text, case: :mixed) do
      {:ok, bytes} -> {:ok, bytes}
      :error -> {:error, field}
    end
  end

  defp rssi(sign, digits) when sign in [?-, ?+] do
    case Integer.parse(digits) do
      {n, ""} ->
        value = if sign == ?-, do: -n, else: n
        if IBeacon.valid_rssi?(value), do: {:ok, value}, else: {:error, :rssi}

      _ ->
        {:error, :rssi}
    end
  end

  defp rssi(_sign, _digits), do: {:error, :rssi}

  @doc """
  The readings of a scan: `%{tag => rssi}` over the beacons among `events` (a tag heard
  twice keeps its strongest reading; other events are ignored).
  """
  @spec readings([event()]) :: %{Beacon.tag_id() => integer()}
  def readings(events) do
    for {:beacon, b, _mac} <- events, reduce: %{} do
      acc -> Map.update(acc, Beacon.tag_id(b), b.rssi, &max(&1, b.rssi))
    end
  end

  @doc """
  What an HM-10 prints for one `AT+DISI?` scan that heard `beacons` (MACs all zero unless
  given as `{beacon, mac}`). Raises `ArgumentError` on a field out of range.

      iex> b = %TartarusLats.Beacon{uuid: "00000000000000000000000000000001", major: 1, minor: 2, tx_power: -59, rssi: -70}
      iex> TartarusLats.HM10.encode_scan([{b, "9CBA6D9A5A3A"}])
      "OK+DISISOK+DISC:4C000215:00000000000000000000000000000001:00010002C5:9CBA6D9A5A3A:-070OK+DISCE"
  """
  @spec encode_scan([Beacon.t() | {Beacon.t(), String.t()}]) :: binary()
  def encode_scan(beacons) do
    IO.iodata_to_binary(["OK+DISIS", Enum.map(beacons, &encode_record/1), "OK+DISCE"])
  end

  defp encode_record(%Beacon{} = b), do: encode_record({b, "000000000000"})

  defp encode_record({%Beacon{} = b, mac}) do
    <<_::binary-9, uuid::binary-16, major::16, minor::16, power::8>> = IBeacon.encode(b)

    unless is_binary(mac) and byte_size(mac) == 12 and match?({:ok, _}, Base.decode16(mac)),
      do:
        raise(
          ArgumentError,
          "invalid MAC: expected 12 uppercase hex digits, got: #{inspect(mac)}"
        )

    unless IBeacon.valid_rssi?(b.rssi),
      do: raise(ArgumentError, "invalid beacon rssi: #{inspect(b.rssi)}")

    sign = if b.rssi < 0, do: "-", else: "+"
    digits = b.rssi |> abs() |> Integer.to_string() |> String.pad_leading(3, "0")

    [
      "OK+DISC:",
      @ibeacon,
      ":",
      Base.encode16(uuid),
      ":",
      Base.encode16(<<major::16, minor::16, power::8>>),
      ":",
      mac,
      ":",
      sign,
      digits
    ]
  end
end
