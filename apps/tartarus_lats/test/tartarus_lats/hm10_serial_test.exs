defmodule TartarusLats.HM10SerialTest do
  # The HM-10 receiver end to end on a real tty: a pseudo-terminal pair made by socat, the
  # platform's serial plugin (stty + an Erlang port) on one end, the bytes of an HM-10
  # written at the other; an agent on the host reads the records through the plugin
  # channel. The device appears after the plugin is attached, vanishes in the middle of a
  # scan and comes back at the same path.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport

  @moduletag :socat

  alias TartarusLats.{Beacon, HM10}

  defmodule Listener do
    @moduledoc false
    # Forwards the :beacon plugin's events to a test process; answers reads through the
    # plugin channel of the host it is on.
    use Tartarus.Agent
    alias Tartarus.Agent, as: A

    @impl true
    def init(%{to: pid}) do
      :ok = A.subscribe(:beacon)
      send(pid, :listening)
      {:stay, %{to: pid}}
    end

    @impl true
    def handle_message({:read, args}, from, s) do
      A.reply(from, A.read(:beacon, args))
      {:stay, s}
    end

    @impl true
    def handle_info({:plugin_event, :beacon, event}, s) do
      send(s.to, {:ble, event})
      {:stay, s}
    end

    def handle_info(_, s), do: {:stay, s}
  end

  @b1 %Beacon{
    uuid: "74278bdab64445208f0c720eaf059935",
    major: 1234,
    minor: 1111,
    tx_power: -59,
    rssi: -61
  }
  @b2 %Beacon{@b1 | minor: 2222, rssi: -77}
  @b3 %Beacon{@b1 | minor: 3333, rssi: -50}

  setup do
    dir = Path.join(System.tmp_dir!(), "tartarus-pty-#{System.unique_integer([:positive])}")
    File.mkdir_p!(dir)
    link = Path.join(dir, "ttyBLE")
    host = :"ble_#{System.unique_integer([:positive])}"
    # The socat processes this test started, killed when it ends whatever happened.
    {:ok, socats} = Agent.start(fn -> [] end)
    Process.put(:socats, socats)

    on_exit(fn ->
      _ = Tartarus.stop_host(host)

      for pid <- Agent.get(socats, & &1),
          do: System.cmd("kill", ["-9", pid], stderr_to_stdout: true)

      Agent.stop(socats)
      File.rm_rf!(dir)
    end)

    %{link: link, host: host}
  end

  test "bytes written at one end become LATS records at the other, across a replug", ctx do
    %{link: link, host: host} = ctx
    {:ok, _} = Tartarus.start_host(host)

    # The plugin `mix tartarus.node --ble LINK` attaches, attached before the device
    # exists: it waits for it.
    [beacon: spec] = Mix.Tasks.Tartarus.Node.plugins!(ble: link, speed: 9600)
    assert spec == HM10.Receiver.plugin(link, speed: 9600)
    :ok = Tartarus.attach_plugin(host, :beacon, spec)

    {:ok, agent} = Tartarus.create_static_agent(host, Listener, %{to: self()})
    assert_receive :listening
    assert {:ok, %{status: :closed, opens: 0}} = Tartarus.read_plugin(host, :beacon, :status)

    # The device appears.
    {socat, _} = socat!(link)
    assert_receive {:ble, {:serial, :up}}, 5_000
    # The plugin asks the HM-10 to scan, through the tty.
    assert_receive {^socat, {:data, "AT+DISI?" <> _}}, 5_000

    # Garbage, then a scan split inside a token and inside a record, with a damaged record
    # and a non-iBeacon device in it.
    scan = HM10.encode_scan([@b1, {@b2, "9CBA6D9A5A3A"}])
    bad = "OK+DISC:4C000215:ZZ278BDAB64445208F0C720EAF059935:04D2045705:9CBA6D9A5A3A:-061"

    other = "OK+DISC:00000000:00000000000000000000000000000000:0000000000:0123456789AB:-080"

    {head, tail} = String.split_at(scan, 4)
    {mid, tail} = String.split_at(tail, 40)
    [scan_start, scan_rest] = [head <> mid, tail]
    {records, ended} = String.split_at(scan_rest, byte_size(scan_rest) - byte_size("OK+DISCE"))

    chunks = [
      <<0, 255, "junk\r\n">>,
      "OK",
      String.slice(scan_start, 2..-1//1),
      records,
      bad,
      other,
      String.slice(ended, 0, 3),
      String.slice(ended, 3..-1//1)
    ]

    # Each chunk is written only once the previous one has been received, so the decoder
    # really sees the frames split.
    Enum.reduce(chunks, 0, fn chunk, sent ->
      Port.command(socat, chunk)
      sent = sent + byte_size(chunk)
      wait_bytes(host, sent)
      sent
    end)

    assert_receive {:ble, {:garbage, <<0, 255, "junk\r\n">>}}, 5_000
    assert_receive {:ble, :scan_started}
    assert_receive {:ble, {:beacon, @b1, "000000000000"}}
    assert_receive {:ble, {:beacon, @b2, "9CBA6D9A5A3A"}}
    assert_receive {:ble, {:bad_record, ^bad, :uuid}}
    assert_receive {:ble, {:other_device, "0123456789AB", -80}}
    assert_receive {:ble, :scan_ended}
    assert_receive {:ble, {:scan_done, done}}
    assert done == HM10.readings([{:beacon, @b1, ""}, {:beacon, @b2, ""}])

    # The node's database agent reads this way: what the scans heard since its last read.
    assert {:ok, {:ok, ^done}} = Tartarus.request(agent, {:read, {:scan, 1}})
    assert {:ok, {:ok, readings}} = Tartarus.request(agent, {:read, {:scan, 2}})
    assert readings == %{}

    # The device vanishes in the middle of a record.
    partial = "OK+DISISOK+DISC:4C000215:74278BDAB644"
    Port.command(socat, partial)
    sent = byte_size(Enum.join(chunks)) + byte_size(partial)
    wait_bytes(host, sent)
    kill_socat!(socat)
    File.rm(link)
    assert_receive {:ble, {:scan_cut, %{}}}, 5_000
    assert_receive {:ble, {:serial, :down, _reason}}, 5_000
    assert {:ok, %{status: status}} = Tartarus.read_plugin(host, :beacon, :status)
    assert status in [:closed, :opening]

    # It comes back at the same path; the half record is not joined to the new bytes.
    {socat2, _} = socat!(link)
    assert_receive {:ble, {:serial, :up}}, 10_000
    Port.command(socat2, "ISC:" <> HM10.encode_scan([@b3]))

    assert_receive {:ble, {:garbage, "ISC:"}}, 5_000
    assert_receive {:ble, :scan_started}
    assert_receive {:ble, {:beacon, @b3, "000000000000"}}
    assert_receive {:ble, {:scan_done, done3}}
    refute_received {:ble, {:bad_record, _, _}}
    assert {:ok, {:ok, ^done3}} = Tartarus.request(agent, {:read, {:scan, 3}})
    assert done3 == %{Beacon.tag_id(@b3) => -50}

    assert {:ok, %{status: :open, opens: 2}} = Tartarus.read_plugin(host, :beacon, :status)

    assert {:ok, %{scans: 2, beacons: 3, bad_records: 1, other_devices: 1, cut_scans: 1}} =
             Tartarus.read_plugin(host, :beacon, :counts)

    # An agent on another host does not reach this receiver.
    other_host = :"ble_other_#{System.unique_integer([:positive])}"
    {:ok, _} = Tartarus.start_host(other_host)

    try do
      {:ok, far} = Tartarus.create_static_agent(other_host, Listener.Far, %{})

      assert {:ok, {:error, {:no_such_plugin, :beacon}}} = Tartarus.request(far, {:read, :counts})
    after
      Tartarus.stop_host(other_host)
    end
  end

  test "the node's database agent logs what an HM-10 on a tty hears", %{link: link, host: host} do
    {:ok, _} = Tartarus.start_host(host)
    :ok = Tartarus.attach_plugin(host, :beacon, HM10.Receiver.plugin(link, backoff_ms: {10, 100}))
    {:ok, _} = Tartarus.create_static_agent(host, Listener, %{to: self()})
    assert_receive :listening
    {socat, _} = socat!(link)
    assert_receive {:ble, {:serial, :up}}, 5_000

    db = {TartarusLats.DatabaseAgent.agent_name(), host}

    {:ok, _} =
      Tartarus.create_static_agent(
        host,
        TartarusLats.DatabaseAgent,
        %{node: :p1, tracker: [window: 2, median: 1]},
        name: TartarusLats.DatabaseAgent.agent_name()
      )

    # One scan a second, as the HM-10 answers AT+DISI?; the driver's phases each second.
    for t <- 1..4 do
      Port.command(socat, HM10.encode_scan([@b1]))
      assert_receive {:ble, {:scan_done, _}}, 5_000
      assert {:ok, _} = Tartarus.request(db, {:sense, t})
      assert {:ok, _} = Tartarus.request(db, {:deliver, t, 1})
      assert {:ok, _} = Tartarus.request(db, {:tick, t})
    end

    # The tag went from beyond to near (-61 dBm): a record of the node's log (thesis Fig. 3.4).
    assert {:ok, %{log: [record | _]}} = Tartarus.request(db, :state)

    assert %{uuid: "74278bdab64445208f0c720eaf059935", major: 1234, minor: 1111, rssi: -61} =
             record

    assert record.region == :near
  end

  test "mix tartarus.node --ble names no application: LATS's environment provides the receiver" do
    # Found from the applications' environments (LATS's mix.exs), the same way by the task
    # and by a release's configuration check (Tartarus.Plugin.Shorthand).
    assert Tartarus.Plugin.Shorthand.ble_receiver() == {:ok, {HM10.Receiver, :plugin}}

    assert [beacon: {Tartarus.Plugin.Serial, opts}] =
             Mix.Tasks.Tartarus.Node.plugins!(ble: "/dev/ttyUSB0", speed: 115_200)

    assert opts[:decoder] == HM10.Receiver and opts[:device] == "/dev/ttyUSB0"
    assert opts[:speed] == 115_200

    # The line the task prints names what it attached, and its help names the same.
    line = Mix.Tasks.Tartarus.Node.plugins_line(beacon: {Tartarus.Plugin.Serial, opts})
    assert line == "plugins: beacon (Tartarus.Plugin.Serial, decoder TartarusLats.HM10.Receiver)"
    help = Mix.Task.moduledoc(Mix.Tasks.Tartarus.Node) |> String.replace(~r/\s+/, " ")
    assert help =~ "`#{line}`"
    refute help =~ "HM10Plugin"

    assert [serial: {Tartarus.Plugin.Serial, [speed: 115_200, device: "/dev/ttyS1"]}] =
             Mix.Tasks.Tartarus.Node.plugins!(serial: "/dev/ttyS1", speed: 115_200)

    assert_raise Mix.Error,
                 ~r/--ble: beacon: \{:ble, \.\.\.\} needs a BLE receiver, and no application/,
                 fn ->
                   Mix.Tasks.Tartarus.Node.plugins!(ble: "/dev/ttyUSB0", ble_receiver: :none)
                 end
  end

  defmodule Listener.Far do
    @moduledoc false
    use Tartarus.Agent
    alias Tartarus.Agent, as: A

    @impl true
    def init(s), do: {:stay, s}

    @impl true
    def handle_message({:read, args}, from, s) do
      A.reply(from, A.read(:beacon, args))
      {:stay, s}
    end
  end

  # socat makes a pseudo-terminal pair: one end linked at `link` (the "device"), the other
  # its own stdin/stdout, i.e. this port.
  defp socat!(link) do
    exe =
      System.find_executable("socat") ||
        flunk("socat is not installed (scripts/test installs it)")

    port =
      Port.open({:spawn_executable, exe}, [
        :binary,
        :exit_status,
        args: ["pty,raw,echo=0,link=#{link}", "STDIO"]
      ])

    {:os_pid, pid} = Port.info(port, :os_pid)
    Agent.update(Process.get(:socats), &[Integer.to_string(pid) | &1])
    {port, pid}
  end

  defp kill_socat!(port) do
    {:os_pid, pid} = Port.info(port, :os_pid)
    System.cmd("kill", [Integer.to_string(pid)])
    assert_receive {^port, {:exit_status, _}}, 5_000
  end

  # Waits until the plugin has received `n` bytes in all.
  defp wait_bytes(host, n) do
    eventually(fn ->
      {:ok, %{bytes: got}} = Tartarus.read_plugin(host, :beacon, :status)
      got >= n
    end)
  end
end
