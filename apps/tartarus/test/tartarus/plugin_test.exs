defmodule Tartarus.PluginTest do
  # Plugins attached to hosts, reached by the agents on those hosts.
  use Tartarus.HostCase, async: false

  alias Tartarus.Plugin.SimSensor
  alias Tartarus.Test.{CrashingPlugin, FailingPlugin, NotAPlugin}

  describe "attach_plugin/3 and plugins/1" do
    test "attaches a sensor and lists it with its description" do
      h = host!()
      assert Tartarus.attach_plugin(h, :temp, {SimSensor, signal: [20.5, 21.0], unit: "C"}) == :ok

      assert Tartarus.plugins(h) == [
               {:temp,
                %{
                  kind: :sensor,
                  unit: "C",
                  reads: [:value, :peek],
                  writes: [:script, :reset],
                  events: [:reading]
                }}
             ]

      assert [{:temp, _}] = Tartarus.status(h).plugins
    end

    test "plugins given at start" do
      h = host!(plugins: [temp: {SimSensor, signal: [1]}, hum: {SimSensor, signal: [2]}])
      assert [{:hum, %{kind: :sensor}}, {:temp, %{kind: :sensor}}] = Tartarus.plugins(h)
    end

    test "the same name twice is refused" do
      h = host!()
      :ok = Tartarus.attach_plugin(h, :temp, {SimSensor, signal: [1]})

      assert Tartarus.attach_plugin(h, :temp, {SimSensor, signal: [2]}) ==
               {:error, {:already_attached, :temp}}
    end

    test "a bad plugin module, a bad spec, a failing device are refused" do
      h = host!()

      assert Tartarus.attach_plugin(h, :x, {NotAPlugin, []}) ==
               {:error, {:not_a_plugin, NotAPlugin}}

      assert Tartarus.attach_plugin(h, :x, {NoSuchModule, []}) ==
               {:error, {:not_a_plugin, NoSuchModule}}

      assert Tartarus.attach_plugin(h, "x", {SimSensor, []}) ==
               {:error, {:bad_plugin, "x", {SimSensor, []}}}

      assert Tartarus.attach_plugin(h, :x, SimSensor) == {:error, {:bad_plugin, :x, SimSensor}}
      assert Tartarus.attach_plugin(h, :x, {FailingPlugin, []}) == {:error, :no_device}

      assert Tartarus.attach_plugin(h, :x, {SimSensor, signal: []}) ==
               {:error, {:bad_option, :signal, "expected a non-empty list of readings, got: []"}}

      assert Tartarus.plugins(h) == []
    end

    test "an unknown host" do
      x = unique_name()

      assert Tartarus.attach_plugin(x, :temp, {SimSensor, signal: [1]}) ==
               {:error, {:unknown_host, addr(x)}}

      assert Tartarus.plugins(x) == {:error, {:unknown_host, addr(x)}}
    end

    test "plugins stop with their host" do
      name = unique_name()
      {:ok, _} = Tartarus.start_host(name, plugins: [temp: {SimSensor, signal: [1]}])
      :ok = Tartarus.stop_host(name)
      {:ok, _} = Tartarus.start_host(name)
      assert Tartarus.plugins(name) == []
      :ok = Tartarus.attach_plugin(name, :temp, {SimSensor, signal: [1]})
      :ok = Tartarus.stop_host(name)
    end
  end

  describe "agents using plugins" do
    test "read, peek, write" do
      h = host!(plugins: [temp: {SimSensor, signal: [1, 2, 3]}])
      ref = {agent!(h), h}
      assert inside(ref, :read, [:temp]) == {:ok, 1}
      assert inside(ref, :read, [:temp, :value]) == {:ok, 2}
      assert inside(ref, :read, [:temp, :peek]) == {:ok, 3}
      assert inside(ref, :read, [:temp, :peek]) == {:ok, 3}
      assert inside(ref, :read, [:temp]) == {:ok, 3}
      # The signal repeats.
      assert inside(ref, :read, [:temp]) == {:ok, 1}
      assert inside(ref, :write, [:temp, :reset]) == :ok
      assert inside(ref, :read, [:temp]) == {:ok, 1}
      assert inside(ref, :write, [:temp, {:script, [9]}]) == :ok
      assert inside(ref, :read, [:temp]) == {:ok, 9}
      assert inside(ref, :read, [:temp]) == {:ok, 9}
    end

    test "bad arguments and missing plugins are errors" do
      h = host!(plugins: [temp: {SimSensor, signal: [1]}])
      ref = {agent!(h), h}
      assert inside(ref, :read, [:temp, :loud]) == {:error, {:bad_argument, :loud}}

      assert inside(ref, :write, [:temp, {:script, []}]) ==
               {:error, {:bad_argument, {:script, []}}}

      assert inside(ref, :write, [:temp, 3]) == {:error, {:bad_argument, 3}}
      assert inside(ref, :read, [:pressure]) == {:error, {:no_such_plugin, :pressure}}
      assert inside(ref, :write, [:pressure, 1]) == {:error, {:no_such_plugin, :pressure}}
      assert inside(ref, :subscribe, [:pressure]) == {:error, {:no_such_plugin, :pressure}}
    end

    test "agents reach only the plugins of the host they are on" do
      [a, b] = line!(2)
      :ok = Tartarus.attach_plugin(a, :temp, {SimSensor, signal: [1]})
      id = agent!(a)
      assert inside({id, a}, :read, [:temp]) == {:ok, 1}
      :ok = Tartarus.move({id, a}, b)
      assert inside({id, a}, :read, [:temp]) == {:error, {:no_such_plugin, :temp}}
    end

    test "a crashing plugin is reported as down" do
      h = host!(plugins: [bad: {CrashingPlugin, []}])
      ref = {agent!(h), h}
      assert inside(ref, :read, [:bad]) == {:ok, :fine}
      assert inside(ref, :read, [:bad, :crash]) == {:error, {:plugin_down, :bad}}
      # The agent survives.
      assert {:ok, _} = Tartarus.request(ref, :state)
    end

    test "subscribers receive events every interval_ms, until they leave" do
      [a, b] = line!(2)
      :ok = Tartarus.attach_plugin(a, :temp, {SimSensor, signal: [5, 6], interval_ms: 5})
      id = agent!(a)
      assert inside({id, a}, :subscribe, [:temp]) == :ok
      # Subscribing twice is fine (and does not double the events).
      assert inside({id, a}, :subscribe, [:temp]) == :ok
      assert_receive {:probe_plugin_event, ^id, :temp, {:reading, first}}, 2_000
      assert_receive {:probe_plugin_event, ^id, :temp, {:reading, second}}, 2_000
      assert Enum.sort([first, second]) == [5, 6]

      :ok = Tartarus.move({id, a}, b)
      assert_receive {:probe_arrived, ^id, %{host: {^b, _}}, _}, 2_000
      flush_events(id)
      refute_receive {:probe_plugin_event, ^id, :temp, _}, 50
    end

    test "plugins without interval_ms send no events" do
      h = host!(plugins: [temp: {SimSensor, signal: [1]}])
      id = agent!(h)
      :ok = inside({id, h}, :subscribe, [:temp])
      refute_receive {:probe_plugin_event, ^id, _, _}, 30
    end
  end

  describe "Tartarus.Plugin.SimSensor as a module" do
    test "init, describe, read, write, handle_info" do
      assert {:ok, s} = SimSensor.init(signal: [1, 2])
      assert %{kind: :sensor, unit: "unit"} = SimSensor.describe(s)
      assert {:ok, 1, s} = SimSensor.read(nil, s)
      assert {:events, [{:reading, 2}], s} = SimSensor.handle_info(:tick, s)
      assert {:events, [], ^s} = SimSensor.handle_info(:other, s)
      assert {:ok, 1, _} = SimSensor.read(:peek, s)
      assert {:error, {:bad_option, :signal, _}} = SimSensor.init([])
      assert {:error, {:bad_option, :signal, _}} = SimSensor.init(signal: :x)
    end
  end

  defp flush_events(id) do
    receive do
      {:probe_plugin_event, ^id, _, _} -> flush_events(id)
    after
      0 -> :ok
    end
  end
end
