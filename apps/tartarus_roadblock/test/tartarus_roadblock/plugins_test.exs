defmodule TartarusRoadblock.PluginsTest do
  # Every simulated device plugin conforms to the `Tartarus.Plugin` behaviour, and agents
  # reach the plugins of the host they are on, and only those.
  use ExUnit.Case, async: false

  alias TartarusArena.{CameraPlugin, DevicePlugin, RobotPlugin, Server, World}

  defmodule Prober do
    @moduledoc false
    # Reads every plugin it is told of on each host of its route, then returns what it saw.
    use Tartarus.Agent

    @impl true
    def init(%{route: route, plugins: plugins}),
      do: probe(%{route: route, plugins: plugins, seen: []})

    @impl true
    def handle_arrival(_ctx, s), do: probe(s)

    defp probe(s) do
      reads = Map.new(s.plugins, fn {name, arg} -> {name, Tartarus.Agent.read(name, arg)} end)
      seen = [{Tartarus.Agent.host(), reads, Tartarus.Agent.capabilities()} | s.seen]

      case s.route do
        [next | rest] -> {:move, next, %{s | route: rest, seen: seen}}
        [] -> {:return, Enum.reverse(seen), s}
      end
    end
  end

  setup do
    world =
      World.new(seed: 3)
      |> World.add_line([{0.2, 0.8}, {2.8, 0.8}])
      |> World.add_robot(:santa, x: 0.5, y: 0.8)
      |> World.add_robot(:claus, x: 2.0, y: 2.0, tool: :claws)
      |> World.add_robot(:rudolph, x: 2.5, y: 2.0, tool: :pusher)

    arena = start_supervised!({Server, world: world})
    %{arena: arena}
  end

  # {label, spec, reads that must work}
  defp simulated(arena) do
    [
      {"SimSensor", {Tartarus.Plugin.SimSensor, signal: [1.0, 2.0]}, [nil, :value, :peek]},
      {"GPIO",
       {Tartarus.Plugin.GPIO,
        pins: [grip: {17, :output}, closed: {27, :input}], backend: Tartarus.Plugin.GPIO.Sim},
       [nil, :all, {:pin, :grip}]},
      {"RobotPlugin (Santa)", {RobotPlugin, arena: arena, robot: :santa},
       [nil, :all, :ultrasonic, :colour, :light, :line, :bumped, :holding, :puck_in_gripper]},
      {"RobotPlugin (Claus)", {RobotPlugin, arena: arena, robot: :claus}, [:holding]},
      {"CameraPlugin (overhead)", {CameraPlugin, arena: arena, pixels: {32, 32}}, [:snapshot]},
      {"CameraPlugin (webcam)",
       {CameraPlugin, arena: arena, pose: {1.4, 0.25, 1.57}, pixels: {32, 24}}, [nil]}
    ] ++
      for device <- DevicePlugin.devices() do
        reads = if device == :motors, do: [nil, :odometry], else: [nil]

        {"DevicePlugin #{device}", {DevicePlugin, arena: arena, robot: :santa, device: device},
         reads}
      end
  end

  test "every simulated plugin conforms to the Tartarus.Plugin behaviour", %{arena: arena} do
    callbacks = Tartarus.Plugin.behaviour_info(:callbacks)
    optional = Tartarus.Plugin.behaviour_info(:optional_callbacks)
    host = :"conform_#{System.unique_integer([:positive])}"
    {:ok, _} = Tartarus.start_host(host)
    on_exit(fn -> Tartarus.stop_host(host) end)

    for {{label, {module, opts}, reads}, i} <- Enum.with_index(simulated(arena)) do
      Code.ensure_loaded!(module)
      behaviours = Keyword.get_values(module.module_info(:attributes), :behaviour)
      assert [Tartarus.Plugin] in behaviours, "#{label}: declares no @behaviour Tartarus.Plugin"

      for {f, a} <- callbacks -- optional do
        assert function_exported?(module, f, a), "#{label}: #{f}/#{a} missing"
      end

      assert {:ok, state} = module.init(opts), label
      d = module.describe(state)
      assert is_atom(d.kind), label

      for key <- [:reads, :writes, :capabilities], Map.has_key?(d, key) do
        assert is_list(Map.fetch!(d, key)), "#{label}: #{key}"
      end

      assert Enum.all?(Map.get(d, :capabilities, []), &is_atom/1), label

      for arg <- reads do
        assert {:ok, _value, _state} = module.read(arg, state), "#{label}: read #{inspect(arg)}"
      end

      assert {:error, {:bad_argument, :no_such_read}, _} = module.read(:no_such_read, state)
      assert {:error, {:bad_argument, :no_such_write}, _} = module.write(:no_such_write, state)

      # ... and the same through a host's plugin channel.
      name = :"p#{i}"
      :ok = Tartarus.attach_plugin(host, name, {module, opts})
      assert {:ok, _} = Tartarus.read_plugin(host, name, hd(reads)), label
      assert {^name, ^d} = List.keyfind(Tartarus.plugins(host), name, 0)
    end
  end

  test "the arena's plugins refuse bad options with a value, not a crash", %{arena: arena} do
    assert {:error, {:bad_option, :arena, "required"}} = CameraPlugin.init([])
    assert {:error, {:bad_option, :robot, "required"}} = RobotPlugin.init(arena: arena)

    assert {:error, {:bad_option, :device, "expected one of " <> _}} =
             DevicePlugin.init(arena: arena, robot: :santa, device: :radar)

    assert {:error, {:bad_option, :robot, "no such robot in the arena"}} =
             DevicePlugin.init(arena: arena, robot: :nobody, device: :ultrasonic)
  end

  test "robots are described by capabilities: Claus has claws, Rudolph a pusher", %{
    arena: arena
  } do
    for {robot, tool} <- [claus: :claws, rudolph: :pusher] do
      host = :"robot_#{robot}_#{System.unique_integer([:positive])}"
      {:ok, _} = Tartarus.start_host(host)
      on_exit(fn -> Tartarus.stop_host(host) end)
      :ok = Tartarus.attach_plugin(host, :robot, {RobotPlugin, arena: arena, robot: robot})

      for {name, device} <- [sonar: :ultrasonic, motors: :motors] do
        :ok =
          Tartarus.attach_plugin(
            host,
            name,
            {DevicePlugin, arena: arena, robot: robot, device: device}
          )
      end

      assert Tartarus.capabilities(host) == %{
               tool => [:robot],
               drive: [:motors, :robot],
               odometry: [:motors],
               ultrasonic: [:sonar]
             }
    end
  end

  test "an agent reaches the plugins of its current host only", %{arena: arena} do
    [a, b] = hosts = for n <- [:a, :b], do: :"reach_#{n}_#{System.unique_integer([:positive])}"

    for h <- hosts do
      {:ok, _} = Tartarus.start_host(h)
      on_exit(fn -> Tartarus.stop_host(h) end)
    end

    :ok = Tartarus.connect(a, b)

    :ok =
      Tartarus.attach_plugin(
        a,
        :sonar,
        {DevicePlugin, arena: arena, robot: :santa, device: :ultrasonic}
      )

    :ok =
      Tartarus.attach_plugin(
        b,
        :camera,
        {CameraPlugin, arena: arena, pixels: {16, 16}, capabilities: [:camera]}
      )

    {:ok, id} =
      Tartarus.create_mobile_agent(
        a,
        Prober,
        %{route: [b, a], plugins: [sonar: nil, camera: :snapshot]},
        owner: self()
      )

    assert_receive {:tartarus_result, ^id, [on_a, on_b, back_on_a]}, 10_000

    {_, reads_a, caps_a} = on_a
    assert {:ok, cm} = reads_a.sonar
    assert cm in 0..200
    assert reads_a.camera == {:error, {:no_such_plugin, :camera}}
    assert caps_a == %{ultrasonic: [:sonar]}

    {_, reads_b, caps_b} = on_b
    assert reads_b.sonar == {:error, {:no_such_plugin, :sonar}}
    assert {:ok, <<137, "PNG", _::binary>>} = reads_b.camera
    assert caps_b == %{camera: [:camera]}

    {_, reads_back, _} = back_on_a
    assert {:ok, _} = reads_back.sonar
    assert reads_back.camera == {:error, {:no_such_plugin, :camera}}
  end
end
