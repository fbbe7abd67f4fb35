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
