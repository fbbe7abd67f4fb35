defmodule TartarusLats.Beacon do
  @moduledoc """
  One received iBeacon advertisement: who sent it and how loud it arrived.

  A beacon is what `TartarusLats.IBeacon.parse/2` returns for a well-formed
  30-byte HM-10 packet. The three identity fields (`uuid`, `major`, `minor`)
  together name a tag bearer; `tag_id/1` packs them into the tuple that the
  rest of LATS (trackers, motion vectors, queries) uses as the tag's key.

      iex> beacon = %TartarusLats.Beacon{
      ...>   uuid: "12121212b64445208f0c720eaf059935",
      ...>   major: 1234,
      ...>   minor: 1111,
      ...>   tx_power: -59,
      ...>   rssi: -63
      ...> }
      iex> TartarusLats.Beacon.tag_id(beacon)
      {"12121212b64445208f0c720eaf059935", 1234, 1111}

  ## Fields

    * `uuid` - the 16-byte proximity UUID as 32 lowercase hex digits without
      dashes, exactly as the thesis's log (Figure 3.4) prints it.
    * `major`, `minor` - 16-bit unsigned integers (0..65535).
    * `tx_power` - the calibrated signal strength at 1 m, in dBm (-128..127,
      decoded from a two's-complement byte; real tags say about -59).
    * `rssi` - the strength the receiver measured for this packet, in dBm.
  """

  @enforce_keys [:uuid, :major, :minor, :tx_power, :rssi]
  defstruct [:uuid, :major, :minor, :tx_power, :rssi]

  @typedoc "32 lowercase hex digits, no dashes."
  @type uuid :: String.t()

  @typedoc "The key that names one tag bearer everywhere in LATS."
  @type tag_id :: {uuid(), major :: 0..65535, minor :: 0..65535}

  @type t :: %__MODULE__{
          uuid: uuid(),
          major: 0..65535,
          minor: 0..65535,
          tx_power: -128..127,
          rssi: integer()
        }

  @doc """
  The tag key `{uuid, major, minor}` of a beacon.

  ## Examples

      iex> TartarusLats.Beacon.tag_id(%TartarusLats.Beacon{uuid: "00000000000000000000000000000001", major: 1, minor: 2, tx_power: -59, rssi: -70})
      {"00000000000000000000000000000001", 1, 2}
  """
  @spec tag_id(t()) :: tag_id()
  def tag_id(%__MODULE__{uuid: uuid, major: major, minor: minor}), do: {uuid, major, minor}
end
