defmodule Tartarus.DevicesTest do
  # The platform's device plugins that need no arena: GPIO pins (simulated backend), the
  # serial plugin's options and its life without a device, and capabilities: what a robot
  # can do, described by its plugins, so agents choose robots by it.
  use Tartarus.HostCase, async: false

  alias Tartarus.Plugin.{GPIO, Serial}

  doctest Tartarus.Plugin.GPIO.Sim
  doctest Tartarus.Plugin.GPIO.Nil
  doctest Tartarus.Plugin.GPIO
  doctest Tartarus.Plugin.Shorthand
  doctest Tartarus.Plugin.Serial.Lines
  doctest Tartarus.Plugin.Serial, only: [check: 1]
  doctest Tartarus.Plugin, import: true

  defmodule Forager do
    @moduledoc false
    # Walks a list of hosts and stops at the first whose plugins offer every capability it
    # needs; reports {:chose, host, capabilities} or {:none, visited} to its payload's :test.
    use Tartarus.Agent
    alias Tartarus.Agent, as: A

    @impl true
    def init(%{route: [first | rest], need: need}),
      do: {:move, first, %{route: rest, need: need, visited: []}}

    @impl true
    def handle_arrival(_ctx, s) do
      caps = A.capabilities()
      s = %{s | visited: s.visited ++ [A.host()]}

      cond do
        Enum.all?(s.need, &Map.has_key?(caps, &1)) ->
          send(A.payload().test, {:chose, A.host(), caps})
          {:stay, s}

        s.route == [] ->
          send(A.payload().test, {:none, s.visited})
          {:stay, s}

        true ->
          [next | rest] = s.route
          {:move, next, %{s | route: rest}}
      end
    end
  end

  describe "GPIO pins (simulated)" do
    setup do
      h = host!()

      :ok =
        Tartarus.attach_plugin(
          h,
          :io,
          {GPIO,
           pins: [led: {17, :output}, relay: {22, :output, 1}, bump: {27, :input}],
           backend: GPIO.Sim}
        )

      %{h: h}
    end

    test "reads, writes outputs, refuses inputs and unknown pins", %{h: h} do
      assert Tartarus.read_plugin(h, :io, :all) == {:ok, %{led: 0, relay: 1, bump: 0}}
      assert Tartarus.write_plugin(h, :io, {:pin, :led, 1}) == :ok
      assert Tartarus.read_plugin(h, :io, {:pin, :led}) == {:ok, 1}
      assert Tartarus.write_plugin(h, :io, {:pin, :bump, 1}) == {:error, {:not_an_output, :bump}}

      assert Tartarus.write_plugin(h, :io, {:pin, :led, 2}) ==
               {:error, {:bad_argument, {:pin, :led, 2}}}

      assert Tartarus.write_plugin(h, :io, {:pin, :nope, 1}) == {:error, {:no_such_pin, :nope}}
      assert Tartarus.read_plugin(h, :io, {:pin, :nope}) == {:error, {:no_such_pin, :nope}}
      assert Tartarus.read_plugin(h, :io, :volts) == {:error, {:bad_argument, :volts}}

      assert Tartarus.write_plugin(h, :io, {:stimulate, :led, 1}) ==
               {:error, {:not_an_input, :led}}

      assert [{:io, %{kind: :gpio, pins: %{bump: {27, :input}}, events: [:edge]}}] =
               Tartarus.plugins(h)
    end

    test "an agent on the host sees the input's edges; the world drives the input", %{h: h} do
      id = agent!(h)
      assert_receive {:probe_init, ^id, _}
      assert {:ok, :ok} = Tartarus.request(id, {:agent, :subscribe, [:io]})

      :ok = Tartarus.write_plugin(h, :io, {:stimulate, :bump, 1})
      assert_receive {:probe_plugin_event, ^id, :io, {:edge, :bump, 1}}
      # No change, no edge.
      :ok = Tartarus.write_plugin(h, :io, {:stimulate, :bump, 1})
      :ok = Tartarus.write_plugin(h, :io, {:stimulate, :bump, 0})
      assert_receive {:probe_plugin_event, ^id, :io, {:edge, :bump, 0}}
      refute_received {:probe_plugin_event, ^id, :io, {:edge, :bump, 1}}
      assert {:ok, {:ok, 0}} = Tartarus.request(id, {:agent, :read, [:io, {:pin, :bump}]})
    end

    test "bad pin tables and backends are refused with the key named" do
      h = host!()

      assert {:error,
              "invalid options given to Tartarus.Plugin.GPIO for key :pins: expected a keyword list" <>
                _} = Tartarus.attach_plugin(h, :x, {GPIO, pins: [a: {1, :sideways}]})

      assert {:error, "invalid options given to Tartarus.Plugin.GPIO for key :pins" <> _} =
               Tartarus.attach_plugin(h, :x, {GPIO, pins: [a: {1, :input}, a: {2, :input}]})

      assert {:error, "invalid options given to Tartarus.Plugin.GPIO for key :backend" <> _} =
               Tartarus.attach_plugin(h, :x, {GPIO, pins: [a: {1, :input}], backend: Enum})
    end
  end

  describe "GPIO without a backend (circuits_gpio's convention)" do
    test "no backend named: the nil backend, which refuses the pins instead of simulating them" do
      h = host!()
      assert Application.get_env(:tartarus, :gpio_backend) == nil

      assert Tartarus.attach_plugin(h, :io, {GPIO, pins: [led: {17, :output}]}) ==
               {:error, {:gpio_open_failed, :led, 17, :no_gpio_backend}}

      assert {:error,
              "Tartarus.Plugin.GPIO: no GPIO backend on this node for pins led (line 17)" <> _} =
               GPIO.check(pins: [led: {17, :output}])

      assert {:error, "Tartarus.Plugin.GPIO: no GPIO backend" <> _} =
               Tartarus.Plugin.Shorthand.parse(:io, {GPIO, pins: [led: {17, :output}]})
               |> then(fn {:error, "io: " <> line} -> {:error, line} end)
    end

    test "the application environment names the node's backend" do
      Application.put_env(:tartarus, :gpio_backend, GPIO.Sim)

      try do
        assert GPIO.check(pins: [led: {17, :output}]) == :ok
        h = host!()
        assert :ok = Tartarus.attach_plugin(h, :io, {GPIO, pins: [led: {17, :output}]})
        assert Tartarus.write_plugin(h, :io, {:pin, :led, 1}) == :ok
        assert Tartarus.read_plugin(h, :io, {:pin, :led}) == {:ok, 1}
      after
        Application.delete_env(:tartarus, :gpio_backend)
      end
    end
  end

  describe "capabilities" do
    test "described by the plugins and the attach option; queried per host" do
      h = host!()

      :ok =
        Tartarus.attach_plugin(
          h,
          :arm,
          {GPIO, pins: [grip: {17, :output}], backend: GPIO.Sim, capabilities: [:claws]}
        )

      :ok =
        Tartarus.attach_plugin(
          h,
          :sonar,
          {Tartarus.Plugin.SimSensor, signal: [40], capabilities: [:ultrasonic]}
        )

      :ok = Tartarus.attach_plugin(h, :temp, {Tartarus.Plugin.SimSensor, signal: [20]})
      assert Tartarus.capabilities(h) == %{claws: [:arm], ultrasonic: [:sonar]}
      assert [{:arm, %{capabilities: [:claws]}}, _, {:temp, temp}] = Tartarus.plugins(h)
      refute Map.has_key?(temp, :capabilities)
      assert Tartarus.capabilities(unique_name()) |> elem(0) == :error

      assert Tartarus.attach_plugin(
               h,
               :bad,
               {Tartarus.Plugin.SimSensor, signal: [1], capabilities: "claws"}
             ) ==
               {:error, {:bad_option, :capabilities, ~s(expected a list of atoms, got: "claws")}}
    end

    test "an agent forages the robots and stops at the one that can do what it needs" do
      [home, santa, rudolph, claus] = line!(4)

      :ok =
        Tartarus.attach_plugin(
          santa,
          :sonar,
          {Tartarus.Plugin.SimSensor, signal: [40], capabilities: [:ultrasonic, :drive]}
        )

      :ok =
        Tartarus.attach_plugin(
          rudolph,
          :pusher,
          {GPIO, pins: [push: {5, :output}], backend: GPIO.Sim, capabilities: [:pusher, :drive]}
        )

      :ok =
        Tartarus.attach_plugin(
          claus,
          :claws,
          {GPIO, pins: [grip: {6, :output}], backend: GPIO.Sim, capabilities: [:claws, :drive]}
        )

      route = for h <- [santa, rudolph, claus], do: {h, node()}
      _ = agent!(home, %{route: route, need: [:claws, :drive]}, module: Forager)
      assert_receive {:chose, {^claus, _}, %{claws: [:claws], drive: [:claws]}}, 5_000

      _ = agent!(home, %{route: route, need: [:camera]}, module: Forager)
      assert_receive {:none, visited}, 5_000
      assert Enum.map(visited, &elem(&1, 0)) == [santa, rudolph, claus]
    end
  end

  defmodule FloodTransport do
    @moduledoc false
    # A transport whose device is the test: it tells the test the plugin's pid, and the
    # test's {:flood, item} messages are the device's items.
    @behaviour Tartarus.Plugin.Serial.Transport

    @impl true
    def open(_device, opts) do
      send(Keyword.fetch!(opts, :test), {:plugin, self()})
      {:ok, :conn}
    end

    @impl true
    def write(_conn, _data), do: :ok
    @impl true
    def close(_conn), do: :ok
    @impl true
    def message({:flood, item}, conn), do: {[item], conn}
    def message(_msg, _conn), do: :ignore
  end

  describe "serial plugin under a flood" do
    # Issue 32: at a faulty device's rate the plugin's mailbox reached 219,000 messages and
    # 1.5 GB, and status/1 took 5 s.
    test "past :max_backlog waiting messages the device's data is dropped and counted" do
      h = host!()

      :ok =
        Tartarus.attach_plugin(
          h,
          :flood,
          {Serial,
           device: "/dev/flood",
           transport: FloodTransport,
           transport_opts: [test: self()],
           max_backlog: 50}
        )

      assert_receive {:plugin, pid}
      send(pid, {:flood, :opened})
      # The plugin is busy (suspended) while the device sends 2,000 chunks.
      :ok = :sys.suspend(pid)
      for _ <- 1..2000, do: send(pid, {:flood, {:data, "x\n"}})
      send(pid, {:flood, {:closed, :unplugged}})
      :ok = :sys.resume(pid)

      assert {:ok, %{bytes: bytes, dropped: %{chunks: chunks, bytes: dropped}} = status} =
               Tartarus.read_plugin(h, :flood, :status)

      # Dropped while more than 50 messages waited behind (the last chunks, the "closed" and
      # perhaps the read): all but the last 49 or 50.
      assert chunks in 1950..1951
      assert bytes + dropped == 4000
      # The device's going away is never dropped.
      assert status.last_error == :unplugged
      assert [{:flood, %{dropped: %{chunks: ^chunks}}}] = Tartarus.plugins(h)
    end
  end

  describe "serial plugin without its device" do
    test "attaches, waits for the device and says why it is not open" do
      h = host!()
      dir = Path.join(System.tmp_dir!(), "tartarus-serial-#{System.unique_integer([:positive])}")
      File.mkdir_p!(dir)
      on_exit(fn -> File.rm_rf!(dir) end)
      missing = Path.join(dir, "ttyNONE")
      regular = Path.join(dir, "plain-file")
      File.write!(regular, "not a tty")

      :ok = Tartarus.attach_plugin(h, :gone, {Serial, device: missing, backoff_ms: {5, 20}})
      :ok = Tartarus.attach_plugin(h, :file, {Serial, device: regular, backoff_ms: {5, 20}})
      assert {:ok, %{status: :closed, opens: 0}} = Tartarus.read_plugin(h, :gone, :status)
      assert Tartarus.write_plugin(h, :gone, {:send, "AT"}) == {:error, :closed}
      assert Tartarus.read_plugin(h, :gone, :last) == {:ok, nil}
      assert Tartarus.read_plugin(h, :gone, :nope) == {:error, {:bad_argument, :nope}}
      eventually(fn -> last_error(h, :gone) == :enoent end)
      eventually(fn -> last_error(h, :file) == {:not_a_device, :regular} end)
      # Nothing was created at the device's path.
      refute File.exists?(missing)

      assert [
               {:file, _},
               {:gone, %{kind: :serial, status: :closed, reads: [:status, :last, :lines]}}
             ] = Tartarus.plugins(h)
    end

    test "bad options name the key" do
      h = host!()

      assert {:error, "required option :device not given to Tartarus.Plugin.Serial"} =
               Tartarus.attach_plugin(h, :s, {Serial, []})

      assert {:error,
              "invalid options given to Tartarus.Plugin.Serial for key :decoder: expected a module implementing Tartarus.Plugin.Serial.Decoder, got: Enum"} =
               Tartarus.attach_plugin(h, :s, {Serial, device: "/dev/null", decoder: Enum})

      assert {:error, "invalid options given to Tartarus.Plugin.Serial for key :backoff_ms" <> _} =
               Tartarus.attach_plugin(h, :s, {Serial, device: "/dev/null", backoff_ms: {10, 1}})

      assert {:error, "invalid options given to Tartarus.Plugin.Serial for key :poll" <> _} =
               Tartarus.attach_plugin(h, :s, {Serial, device: "/dev/null", poll: {"AT", 0}})
    end
  end

  defp last_error(h, name) do
    {:ok, %{last_error: error}} = Tartarus.read_plugin(h, name, :status)
    error
  end
end
