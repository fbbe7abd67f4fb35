defmodule TartarusLats.IBeacon do
  @moduledoc """
  Parser (and encoder) for the 30-byte iBeacon packets an HM-10 tag emits.

  The thesis (§3.3.2) describes each packet as five fields; this module fixes
  the exact bytes, following Apple's iBeacon advertisement layout that the
  HM-10 uses in beacon mode (`AT+IBEA1`):

  | offset | bytes | field      | value                                        |
  |-------:|------:|------------|----------------------------------------------|
  |      0 |     9 | preamble   | `02 01 06 1A FF 4C 00 02 15` (fixed)          |
  |      9 |    16 | UUID       | proximity UUID, big-endian                    |
  |     25 |     2 | major      | unsigned, big-endian                          |
  |     27 |     2 | minor      | unsigned, big-endian                          |
  |     29 |     1 | Tx power   | two's complement dBm at 1 m (e.g. `C5` = -59) |

  The preamble is two BLE AD structures: `02 01 06` (flags: LE general
  discoverable, BR/EDR not supported) and the head of `1A FF ...`, a 26-byte
  manufacturer-specific structure whose company id is Apple's `4C 00`
  (0x004C, little-endian), followed by the iBeacon type `02` and the
  remaining length `15` (21 bytes: UUID + major + minor + Tx power).

  The RSSI is not in the packet: the receiver reports it beside the packet,
  so `parse/2` takes it as a second argument and stores it in the
  `TartarusLats.Beacon`. It must be an integer in `-127..25` dBm (the
  widest range the thesis reports for real receivers).

  ## Example

      iex> beacon = %TartarusLats.Beacon{uuid: "12121212b64445208f0c720eaf059935",
      ...>   major: 1234, minor: 1111, tx_power: -59, rssi: -61}
      iex> packet = TartarusLats.IBeacon.encode(beacon)
      iex> byte_size(packet)
      30
      iex> TartarusLats.IBeacon.parse(packet, -61)
      {:ok, beacon}
      iex> TartarusLats.IBeacon.parse(binary_part(packet, 0, 20), -61)
      {:error, {:bad_length, 20}}

  ## Errors

  `parse/2` never raises, whatever it is given (a property test feeds it
  random bytes). It returns one of:

    * `{:error, :not_a_binary}` - the packet is not a binary;
    * `{:error, {:bad_length, n}}` - the packet has `n` bytes, not 30;
    * `{:error, :bad_preamble}` - the first 9 bytes are not the preamble above;
    * `{:error, {:bad_rssi, value}}` - the RSSI is not an integer in range.
  """

  alias TartarusLats.Beacon

  @preamble <<0x02, 0x01, 0x06, 0x1A, 0xFF, 0x4C, 0x00, 0x02, 0x15>>
  @packet_size 30
  @rssi_min -127
  @rssi_max 25

  @typedoc "Why a packet was rejected."
  @type reason ::
          :not_a_binary
          | {:bad_length, non_neg_integer()}
          | :bad_preamble
          | {:bad_rssi, term()}

  @doc """
  The fixed 9-byte preamble every valid packet starts with.

      iex> TartarusLats.IBeacon.preamble()
      <<2, 1, 6, 26, 255, 76, 0, 2, 21>>
  """
  @spec preamble() :: <<_::72>>
  def preamble, do: @preamble

  @doc "The size of a packet in bytes (30)."
  @spec packet_size() :: 30
  def packet_size, do: @packet_size

  @doc """
  Parses one packet with the RSSI the receiver measured for it.

  Checks, in this order: the packet is a binary, it is 30 bytes long, it
  starts with the preamble, and the RSSI is an integer in range. The first
  failed check is the reason returned.

  ## Examples

      iex> packet = TartarusLats.IBeacon.preamble() <> <<0::128, 0, 7, 0, 9, 0xC5>>
      iex> TartarusLats.IBeacon.parse(packet, -70)
      {:ok, %TartarusLats.Beacon{uuid: "00000000000000000000000000000000", major: 7, minor: 9, tx_power: -59, rssi: -70}}
      iex> TartarusLats.IBeacon.parse(<<0::240>>, -70)
      {:error, :bad_preamble}
      iex> TartarusLats.IBeacon.parse(packet, 0.5)
      {:error, {:bad_rssi, 0.5}}
      iex> TartarusLats.IBeacon.parse(:nope, -70)
      {:error, :not_a_binary}
  """
  @spec parse(term(), term()) :: {:ok, Beacon.t()} | {:error, reason()}
  def parse(packet, _rssi) when not is_binary(packet), do: {:error, :not_a_binary}

  def parse(packet, _rssi) when byte_size(packet) != @packet_size,
    do: {:error, {:bad_length, byte_size(packet)}}

  def parse(<<@preamble, uuid::binary-size(16), major::16, minor::16, tx::signed-8>>, rssi) do
    if valid_rssi?(rssi) do
      {:ok,
       %Beacon{
         uuid: Base.encode16(uuid, case: :lower),
         major: major,
         minor: minor,
         tx_power: tx,
         rssi: rssi
       }}
    else
      {:error, {:bad_rssi, rssi}}
    end
  end

  def parse(_packet, _rssi), do: {:error, :bad_preamble}

  @doc """
  Whether `value` is an RSSI this module accepts (an integer in -127..25 dBm).

      iex> TartarusLats.IBeacon.valid_rssi?(-59)
      true
      iex> TartarusLats.IBeacon.valid_rssi?(-200)
      false
  """
  @spec valid_rssi?(term()) :: boolean()
  def valid_rssi?(rssi), do: is_integer(rssi) and rssi >= @rssi_min and rssi <= @rssi_max

  @doc """
  Encodes a beacon back into its 30-byte packet (the RSSI is not part of it).

  Used by tests and the emulated world. The UUID may be given with or
  without dashes, in either case. Raises `ArgumentError` naming the field
  when a field is out of range.

      iex> beacon = %TartarusLats.Beacon{uuid: "12121212-B644-4520-8F0C-720EAF059935",
      ...>   major: 1, minor: 2, tx_power: -59, rssi: -60}
      iex> TartarusLats.IBeacon.encode(beacon) |> binary_part(25, 5)
      <<0, 1, 0, 2, 197>>
  """
  @spec encode(Beacon.t()) :: <<_::240>>
  def encode(%Beacon{uuid: uuid, major: major, minor: minor, tx_power: tx}) do
    uuid_bytes =
      case uuid_to_binary(uuid) do
        {:ok, bytes} ->
          bytes

        :error ->
          raise ArgumentError,
                "invalid beacon uuid: expected 32 hex digits, got: #{inspect(uuid)}"
      end

    check_range!(:major, major, 0..65535)
    check_range!(:minor, minor, 0..65535)
    check_range!(:tx_power, tx, -128..127)
    <<@preamble, uuid_bytes::binary, major::16, minor::16, tx::signed-8>>
  end

  @doc """
  Converts a UUID given as hex text (dashes and case ignored) to its 16 bytes.

      iex> TartarusLats.IBeacon.uuid_to_binary("00000000-0000-0000-0000-0000000000ff")
      {:ok, <<0::120, 255>>}
      iex> TartarusLats.IBeacon.uuid_to_binary("xyz")
      :error
  """
  @spec uuid_to_binary(term()) :: {:ok, <<_::128>>} | :error
  def uuid_to_binary(uuid) when is_binary(uuid) do
    case Base.decode16(String.replace(uuid, "-", ""), case: :mixed) do
      {:ok, <<_::128>> = bytes} -> {:ok, bytes}
      _ -> :error
    end
  end

  def uuid_to_binary(_), do: :error

  defp check_range!(field, value, range) do
    unless is_integer(value) and value in range do
      raise ArgumentError,
            "invalid beacon #{field}: expected an integer in #{inspect(range)}, got: #{inspect(value)}"
    end
  end
end
