defmodule TartarusLats.HM10ReceiverTest do
  # The HM-10 decoder of the serial plugin, without a tty: scans merged per read, a scan cut
  # by the device going away dropped, the counts.
  use ExUnit.Case, async: true
  doctest TartarusLats.HM10.Receiver

  alias TartarusLats.{Beacon, HM10}
  alias TartarusLats.HM10.Receiver

  @b %Beacon{
    uuid: "74278bdab64445208f0c720eaf059935",
    major: 1,
    minor: 2,
    tx_power: -59,
    rssi: -70
  }

  test "scans since the last read are merged, strongest reading kept; a cut scan is dropped" do
    {:ok, r} = Receiver.init([])
    {_, r} = Receiver.feed(HM10.encode_scan([@b]), r)
    {_, r} = Receiver.feed(HM10.encode_scan([%Beacon{@b | rssi: -60}]), r)
    # A third scan, cut: the device goes away after its first record.
    scan = HM10.encode_scan([%Beacon{@b | rssi: -40}])
    {_, r} = Receiver.feed(binary_part(scan, 0, byte_size(scan) - byte_size("OK+DISCE")), r)
    {cut, r} = Receiver.reset(r)
    assert cut == [{:scan_cut, %{Beacon.tag_id(@b) => -40}}]
    assert {:ok, readings, r} = Receiver.read({:scan, 5}, r)
    assert readings == %{Beacon.tag_id(@b) => -60}
    assert {:ok, {5, ^readings}, r} = Receiver.read(:last, r)

    assert {:ok, %{scans: 2, beacons: 3, cut_scans: 1, bad_records: 0}, _} =
             Receiver.read(:counts, r)
  end

  # Issue 32: a device that never ends its scan grew the unfinished scan without bound
  # (11 MB, 39,000 tags in 30 s at 100 KiB/s).
  test "a scan that never ends: the decoder's state stays bounded, the dropped readings counted" do
    beacon = fn i -> %Beacon{@b | major: div(i, 65_536), minor: rem(i, 65_536)} end

    # 20,000 tags, in chunks of 500 records (~47 KB each), and no OK+DISCE.
    feed = fn r, range ->
      scan = HM10.encode_scan(Enum.map(range, beacon))
      records = binary_part(scan, 8, byte_size(scan) - 16)
      {_events, r} = Receiver.feed(records, r)
      r
    end

    {:ok, r} = Receiver.init(max_tags: 100)
    {_events, r} = Receiver.feed("OK+DISIS", r)
    r = feed.(r, 0..499)
    size = :erts_debug.flat_size(r)

    r = Enum.reduce(1..39, r, fn k, r -> feed.(r, (k * 500)..(k * 500 + 499)) end)
    assert :erts_debug.flat_size(r) <= size

    assert {:ok, %{beacons: 20_000, dropped_readings: 19_900, scans: 0}, r} =
             Receiver.read(:counts, r)

    # A tag already in the scan still gets its strongest reading.
    {_events, r} = Receiver.feed(HM10.encode_scan([%Beacon{beacon.(5) | rssi: -40}]), r)
    assert {:ok, %{cut_scans: 1, scans: 1}, r} = Receiver.read(:counts, r)
    assert {:ok, readings, _r} = Receiver.read({:scan, 1}, r)
    assert readings == %{Beacon.tag_id(beacon.(5)) => -40}

    assert {:error, "invalid options given to TartarusLats.HM10.Receiver for key :max_tags" <> _} =
             Receiver.init(max_tags: 0)
  end

  test "the plugin spec" do
    assert Receiver.plugin("/dev/ttyUSB0", speed: 115_200) ==
             {Tartarus.Plugin.Serial,
              [
                device: "/dev/ttyUSB0",
                decoder: Receiver,
                poll: {"AT+DISI?", 1000},
                speed: 115_200
              ]}
  end
end
