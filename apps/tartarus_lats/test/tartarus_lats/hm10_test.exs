defmodule TartarusLats.HM10Test do
  use ExUnit.Case, async: true
  doctest TartarusLats.HM10

  alias TartarusLats.{Beacon, HM10}
  alias TartarusTools.Prop

  @b1 %Beacon{
    uuid: "74278bdab64445208f0c720eaf059935",
    major: 1234,
    minor: 1111,
    tx_power: -59,
    rssi: -61
  }
  @b2 %Beacon{@b1 | major: 7, minor: 9, tx_power: 4, rssi: -98}

  test "a capture as the HM-10 prints it: line breaks, a damaged record, another device" do
    capture =
      "OK+DISIS\r\n" <>
        "OK+DISC:4C000215:74278BDAB64445208F0C720EAF059935:04D2045705:9CBA6D9A5A3A:-061\r\n" <>
        "OK+DISC:4C000215:74278BDAB6444520:04D2045705:9CBA6D9A5A3A:-061" <>
        "OK+DISC:00000000:00000000000000000000000000000000:0000000000:0017EA090A0B:-077" <>
        "OK+DISCE\r\n"

    events = HM10.parse_all(capture)

    assert [
             :scan_started,
             {:beacon, beacon, "9CBA6D9A5A3A"},
             {:bad_record, _, _},
             {:other_device, "0017EA090A0B", -77},
             :scan_ended
           ] = events

    # Major 0x04D2, minor 0x0457, measured power 0x05.
    assert beacon == %Beacon{@b1 | tx_power: 5}
    assert HM10.readings(events) == %{Beacon.tag_id(@b1) => -61}
  end

  test "a bad field is named; the parser goes on with the next record" do
    good = HM10.encode_scan([@b1])
    bad = String.replace(good, "-061", "-0x1")
    events = HM10.parse_all(bad <> good)
    assert [:scan_started, {:bad_record, _, :rssi}, :scan_ended | rest] = events
    assert rest == [:scan_started, {:beacon, @b1, "000000000000"}, :scan_ended]
  end

  test "a tag heard twice in a scan keeps its strongest reading" do
    events = HM10.parse_all(HM10.encode_scan([@b1, %{@b1 | rssi: -50}, @b2]))
    assert HM10.readings(events) == %{Beacon.tag_id(@b1) => -50, Beacon.tag_id(@b2) => -98}
  end

  test "the buffer is bounded: a record that never completes is reported as garbage" do
    {p, []} = HM10.feed(HM10.new(), "OK+DISC:")
    {_p, events} = HM10.feed(p, String.duplicate("\r", 2000))
    # Line breaks inside a record make it a bad record, never a stuck parser.
    assert events != []
  end

  # Scans of random beacons, encoded, with random garbage between them, cut into random
  # chunks: the events are the same whatever the chunking, every beacon comes back, and
  # random bytes never make the parser raise.
  defp beacon do
    :proper_types.bind(
      {:proper_types.binary(16), :proper_types.integer(0, 65535), :proper_types.integer(0, 65535),
       :proper_types.integer(-128, 127), :proper_types.integer(-127, 25)},
      fn {uuid, major, minor, tx, rssi} ->
        %Beacon{
          uuid: Base.encode16(uuid, case: :lower),
          major: major,
          minor: minor,
          tx_power: tx,
          rssi: rssi
        }
      end,
      false
    )
  end

  defp feed_chunks(bytes, cuts) do
    points = cuts |> Enum.map(&rem(&1, byte_size(bytes) + 1)) |> Enum.sort() |> Enum.uniq()

    {chunks, last, _} =
      Enum.reduce(points, {[], 0, bytes}, fn p, {acc, from, b} ->
        {[binary_part(b, from, p - from) | acc], p, b}
      end)

    chunks = Enum.reverse([binary_part(bytes, last, byte_size(bytes) - last) | chunks])

    {p, events} =
      Enum.reduce(chunks, {HM10.new(), []}, fn c, {p, acc} ->
        {p, ev} = HM10.feed(p, c)
        {p, acc ++ ev}
      end)

    {_, tail} = HM10.feed(p, <<>>)
    events ++ tail
  end

  test "property: chunking changes nothing, every beacon comes back, junk never raises" do
    prop =
      :proper.forall(
        {:proper_types.list(:proper_types.list(beacon())),
         :proper_types.list(:proper_types.non_neg_integer())},
        fn {scans, cuts} ->
          Prop.safely(fn ->
            bytes = Enum.map_join(scans, "\r\n", &HM10.encode_scan/1)
            whole = HM10.parse_all(bytes)
            chunked = feed_chunks(bytes, cuts)

            whole == chunked and
              for({:beacon, b, _} <- whole, do: b) == List.flatten(scans) and
              not Enum.any?(whole, &match?({:garbage, _}, &1))
          end)
        end
      )

    assert Prop.check(prop, 300) == true

    junk =
      :proper.forall(
        {:proper_types.binary(), :proper_types.list(:proper_types.non_neg_integer())},
        fn {bytes, cuts} ->
          Prop.safely(fn ->
            bytes = "OK+DISC:" <> bytes <> HM10.encode_scan([@b1])
            events = feed_chunks(bytes, cuts)
            is_list(events) and {:beacon, @b1, "000000000000"} in events
          end)
        end
      )

    assert Prop.check(junk, 300) == true
  end
end
