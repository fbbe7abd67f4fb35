defmodule TartarusLats.IBeaconTest do
  use ExUnit.Case, async: true
  doctest TartarusLats.IBeacon
  doctest TartarusLats.Beacon

  alias TartarusLats.{Beacon, IBeacon}
  alias TartarusTools.Prop

  @beacon %Beacon{
    uuid: "12121212b64445208f0c720eaf059935",
    major: 1234,
    minor: 1111,
    tx_power: -59,
    rssi: -66
  }

  test "parses a valid packet with every field" do
    packet = IBeacon.encode(@beacon)
    assert <<2, 1, 6, 0x1A, 0xFF, 0x4C, 0, 2, 0x15, _::binary>> = packet
    assert {:ok, @beacon} = IBeacon.parse(packet, -66)
  end

  test "decodes Tx power as two's complement" do
    packet = IBeacon.encode(%{@beacon | tx_power: 4})
    assert {:ok, %{tx_power: 4}} = IBeacon.parse(packet, -66)
    <<head::binary-size(29), _>> = packet
    assert {:ok, %{tx_power: -1}} = IBeacon.parse(head <> <<0xFF>>, -66)
  end

  test "rejects truncated and overlong packets with their length" do
    packet = IBeacon.encode(@beacon)
    assert {:error, {:bad_length, 29}} = IBeacon.parse(binary_part(packet, 0, 29), -60)
    assert {:error, {:bad_length, 0}} = IBeacon.parse("", -60)
    assert {:error, {:bad_length, 31}} = IBeacon.parse(packet <> <<0>>, -60)
  end

  test "rejects a wrong preamble" do
    <<_, rest::binary>> = IBeacon.encode(@beacon)
    assert {:error, :bad_preamble} = IBeacon.parse(<<3>> <> rest, -60)
    # not Apple's company id
    <<pre::binary-size(5), _::16, tail::binary>> = IBeacon.encode(@beacon)
    assert {:error, :bad_preamble} = IBeacon.parse(pre <> <<0x59, 0x00>> <> tail, -60)
  end

  test "rejects a bad rssi" do
    packet = IBeacon.encode(@beacon)

    for bad <- [-128, 26, nil, "-60", -60.5] do
      assert {:error, {:bad_rssi, ^bad}} = IBeacon.parse(packet, bad)
    end
  end

  test "rejects non-binaries" do
    assert {:error, :not_a_binary} = IBeacon.parse(<<1::3>>, -60)
    assert {:error, :not_a_binary} = IBeacon.parse([1, 2], -60)
  end

  test "encode raises naming the bad field" do
    assert_raise ArgumentError, ~r/major/, fn -> IBeacon.encode(%{@beacon | major: 70_000}) end
    assert_raise ArgumentError, ~r/uuid/, fn -> IBeacon.encode(%{@beacon | uuid: "zz"}) end
  end

  test "property: random bytes never crash the parser" do
    prop =
      :proper.forall(
        {:proper_types.binary(), :proper_types.integer(-200, 200)},
        fn {bytes, rssi} ->
          Prop.safely(fn ->
            case IBeacon.parse(bytes, rssi) do
              {:ok, %Beacon{}} -> byte_size(bytes) == 30
              {:error, _} -> true
            end
          end)
        end
      )

    assert Prop.check(prop, 500) == true
  end

  test "property: random 30-byte packets behind the preamble always parse" do
    prop =
      :proper.forall(
        {:proper_types.binary(21), :proper_types.integer(-127, 25)},
        fn {body, rssi} ->
          Prop.safely(fn ->
            packet = IBeacon.preamble() <> body
            {:ok, beacon} = IBeacon.parse(packet, rssi)
            IBeacon.encode(beacon) == packet
          end)
        end
      )

    assert Prop.check(prop, 300) == true
  end

  test "property: encode -> parse round-trips" do
    prop =
      :proper.forall(
        {:proper_types.binary(16), :proper_types.integer(0, 65535),
         :proper_types.integer(0, 65535), :proper_types.integer(-128, 127),
         :proper_types.integer(-127, 25)},
        fn {uuid, major, minor, tx, rssi} ->
          Prop.safely(fn ->
            beacon = %Beacon{
              uuid: Base.encode16(uuid, case: :lower),
              major: major,
              minor: minor,
              tx_power: tx,
              rssi: rssi
            }

            IBeacon.parse(IBeacon.encode(beacon), rssi) == {:ok, beacon}
          end)
        end
      )

    assert Prop.check(prop, 300) == true
  end
end
