defmodule TartarusFirmwareTest do
  # What can be checked of the Nerves firmware (firmware/) without hex and without a Pi:
  # every source parses; the adapters compile against test doubles of Circuits.UART and
  # Circuits.GPIO (test/support/circuits_doubles.exs) with no call to anything missing;
  # each defines every callback of the behaviour it claims; and driven through their plugin
  # contract on a host, with the doubles standing in for the hardware, they behave as the
  # simulated devices do.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport

  @moduletag :firmware

  @firmware Path.expand("../firmware", __DIR__)
  @doubles Path.expand("support/circuits_doubles.exs", __DIR__)

  defmodule Listener do
    @moduledoc false
    use Tartarus.Agent
    alias Tartarus.Agent, as: A

    @impl true
    def init(%{to: pid, plugin: plugin}) do
      :ok = A.subscribe(plugin)
      send(pid, {:listening, plugin})
      {:stay, %{to: pid}}
    end

    @impl true
    def handle_info({:plugin_event, plugin, event}, s) do
      send(s.to, {:event, plugin, event})
      {:stay, s}
    end

    def handle_info(_, s), do: {:stay, s}
  end

  setup_all do
    files = Path.wildcard(Path.join(@firmware, "lib/**/*.ex"))
    # Compiled together, so a call to a function the doubles (or the platform) lack is
    # reported like any undefined remote call.
    {:ok, modules, warnings} =
      ExUnit.CaptureIO.with_io(:stderr, fn ->
        Kernel.ParallelCompiler.compile([@doubles | files])
      end)
      |> elem(0)

    {:ok, _} = uart().start_link()
    {:ok, _} = gpio().start_link()
    %{modules: modules, warnings: warnings, files: files}
  end

  test "every .ex and .exs under firmware/ parses" do
    sources = Path.wildcard(Path.join(@firmware, "**/*.{ex,exs}"), match_dot: true)
    names = Enum.map(sources, &Path.relative_to(&1, @firmware))

    for must <- ~w(mix.exs config/config.exs config/target.exs config/host.exs
                   lib/tartarus_firmware/uart.ex lib/tartarus_firmware/gpio_backend.ex),
        do: assert(must in names)

    for file <- sources do
      assert {:ok, _} = Code.string_to_quoted(File.read!(file), file: file), file
    end
  end

  test "the firmware compiles against the doubles with no warning (no missing call)", ctx do
    assert ctx.warnings == []

    for m <- [
          TartarusFirmware.UART,
          TartarusFirmware.GPIOBackend,
          TartarusFirmware.HM10,
          TartarusFirmware.GPIO,
          TartarusFirmware.Distribution,
          TartarusFirmware.Node
        ],
        do: assert(m in ctx.modules)
  end

  test "each adapter defines every callback of the behaviour it claims" do
    for {module, behaviour} <- [
          {TartarusFirmware.UART, Tartarus.Plugin.Serial.Transport},
          {TartarusFirmware.GPIOBackend, Tartarus.Plugin.GPIO.Backend},
          {TartarusFirmware.HM10, Tartarus.Plugin},
          {TartarusFirmware.GPIO, Tartarus.Plugin}
        ] do
      assert behaviour in List.flatten(
               Keyword.get_values(module.__info__(:attributes), :behaviour)
             )

      missing = behaviour.behaviour_info(:callbacks) -- module.__info__(:functions)
      assert missing -- behaviour.behaviour_info(:optional_callbacks) == [], inspect(module)
    end
  end

  test "the HM-10 over Circuits.UART: records, scans, unplug and replug" do
    host = :"fw_hm10_#{System.unique_integer([:positive])}"
    dev = "ttyAMA#{System.unique_integer([:positive])}"

    {:ok, _} =
      Tartarus.start_host(host,
        plugins: [
          beacon:
            {TartarusFirmware.HM10, device: "/dev/" <> dev, poll_ms: 20, backoff_ms: {5, 20}}
        ]
      )

    on_exit(fn -> Tartarus.stop_host(host) end)
    {:ok, _} = Tartarus.create_static_agent(host, Listener, %{to: self(), plugin: :beacon})
    assert_receive {:listening, :beacon}
    assert {:ok, %{status: :closed}} = Tartarus.read_plugin(host, :beacon, :status)

    uart().plug(dev)
    assert_receive {:event, :beacon, {:serial, :up}}, 5_000
    eventually(fn -> String.contains?(uart().written(dev) || "", "AT+DISI?") end)

    b = %TartarusLats.Beacon{
      uuid: "74278bdab64445208f0c720eaf059935",
      major: 7,
      minor: 8,
      tx_power: -59,
      rssi: -66
    }

    scan = TartarusLats.HM10.encode_scan([b])
    {a, z} = String.split_at("zz" <> scan, 30)
    :ok = uart().inject(dev, a)
    :ok = uart().inject(dev, z)
    assert_receive {:event, :beacon, {:garbage, "zz"}}, 5_000
    assert_receive {:event, :beacon, {:beacon, ^b, "000000000000"}}, 5_000
    assert_receive {:event, :beacon, {:scan_done, readings}}, 5_000
    assert {:ok, ^readings} = Tartarus.read_plugin(host, :beacon, {:scan, 1})
    assert readings == %{TartarusLats.Beacon.tag_id(b) => -66}

    :ok = uart().inject(dev, "OK+DISIS")
    assert_receive {:event, :beacon, :scan_started}, 5_000
    uart().unplug(dev)
    assert_receive {:event, :beacon, {:scan_cut, %{}}}, 5_000
    assert_receive {:event, :beacon, {:serial, :down, :eio}}

    uart().plug(dev)
    assert_receive {:event, :beacon, {:serial, :up}}, 5_000
    assert {:ok, %{status: :open, opens: 2}} = Tartarus.read_plugin(host, :beacon, :status)

    assert {:ok, %{kind: :ble_receiver, chip: :hm10}} =
             host |> Tartarus.plugins() |> Keyword.fetch(:beacon)
  end

  defmodule Service do
    @moduledoc false
    # A service as the firmware starts one: start_link(opts ++ [host: host]).
    def start_link(opts) do
      Agent.start_link(fn -> send(opts[:to], {:service_started, opts[:host], self()}) end)
    end
  end

  @tag :tmp_dir
  test "the node starts its services and links its neighbours as soon as they answer (issue 41)",
       %{
         tmp_dir: dir
       } do
    neighbour = {:"fw41_nb_#{System.unique_integer([:positive])}", node()}
    Application.put_env(:tartarus_firmware, :data, dir)
    Application.put_env(:tartarus_firmware, :plugins, [])
    Application.put_env(:tartarus_firmware, :neighbours, [neighbour])
    me = self()
    Application.put_env(:tartarus_firmware, :services, [{__MODULE__.Service, to: me}])
    # (Compiled at run time, in setup_all: named through a variable.)
    fw_node = Module.concat(TartarusFirmware, Node)
    fw = TartarusFirmware
    {:ok, pid} = fw_node.start_link([])

    try do
      # The services start with the host (LATS's Device on a Pi), given the host.
      host = fw.host()
      assert_receive {:service_started, {^host, _}, service}, 10_000
      Process.put(:service, service)

      # The neighbour is not up yet: the link waits for it.
      assert fw_node.missing_neighbours() == [neighbour]
      {:ok, _} = Tartarus.start_host(elem(neighbour, 0))
      eventually(fn -> fw_node.missing_neighbours() == [] end, 10_000)
      assert neighbour in Tartarus.neighbours(fw.host())
    after
      GenServer.stop(pid)
      # The services stop with the node.
      if service = Process.get(:service),
        do: eventually(fn -> not Process.alive?(service) end, 5_000)

      Tartarus.stop_host(fw.host())
      Tartarus.stop_host(elem(neighbour, 0))

      for key <- [:data, :plugins, :neighbours, :services],
          do: Application.delete_env(:tartarus_firmware, key)
    end
  end

  test "GPIO over Circuits.GPIO: the simulated pins' contract on the Pi's pins" do
    host = :"fw_gpio_#{System.unique_integer([:positive])}"

    {led, button} =
      {1000 + System.unique_integer([:positive]), 2000 + System.unique_integer([:positive])}

    {:ok, _} =
      Tartarus.start_host(host,
        plugins: [
          io: {TartarusFirmware.GPIO, pins: [led: {led, :output, 1}, button: {button, :input}]}
        ]
      )

    on_exit(fn -> Tartarus.stop_host(host) end)
    {:ok, _} = Tartarus.create_static_agent(host, Listener, %{to: self(), plugin: :io})
    assert_receive {:listening, :io}

    assert Tartarus.read_plugin(host, :io, :all) == {:ok, %{led: 1, button: 0}}
    assert Tartarus.write_plugin(host, :io, {:pin, :led, 0}) == :ok
    assert gpio().level(led) == 0

    assert Tartarus.write_plugin(host, :io, {:pin, :button, 1}) ==
             {:error, {:not_an_output, :button}}

    # Real inputs are driven by the world, not by a write.
    assert Tartarus.write_plugin(host, :io, {:stimulate, :button, 1}) ==
             {:error, {:bad_argument, {:stimulate, :button, 1}}}

    :ok = gpio().drive(button, 1)
    assert_receive {:event, :io, {:edge, :button, 1}}, 5_000
    assert Tartarus.read_plugin(host, :io, {:pin, :button}) == {:ok, 1}

    assert [{:io, %{kind: :gpio, writes: [:pin]}}] = Tartarus.plugins(host)
  end

  # The doubles' control modules exist only once setup_all has compiled them.
  defp uart, do: Module.concat(Circuits.UART, Double)
  defp gpio, do: Module.concat(Circuits.GPIO, Double)
end
