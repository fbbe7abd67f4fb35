defmodule TartarusArena.PluginTest do
  use ExUnit.Case, async: false

  alias TartarusArena.{CameraPlugin, PNG, RobotPlugin, Server, World}

  defmodule Driver do
    @moduledoc false
    # An agent that senses and drives the robot of the host it is on.
    use Tartarus.Agent

    @impl true
    def init(s), do: {:stay, s}

    @impl true
    def handle_message({:read, what}, from, s) do
      Tartarus.Agent.reply(from, Tartarus.Agent.read(:robot, what))
      {:stay, s}
    end

    def handle_message({:write, what}, from, s) do
      Tartarus.Agent.reply(from, Tartarus.Agent.write(:robot, what))
      {:stay, s}
    end

    def handle_message(:snapshot, from, s) do
      Tartarus.Agent.reply(from, Tartarus.Agent.read(:camera, :snapshot))
      {:stay, s}
    end
  end

  defmodule Follower do
    @moduledoc false
    # An agent carrying a PFA: each :step it reads the line sensors of its host's robot and
    # sets the wheels.
    use Tartarus.Agent

    @impl true
    def init(pfa) do
      Tartarus.Agent.add_module(pfa)
      {:stay, %{pfa: pfa, ctl: pfa.init([])}}
    end

    @impl true
    def handle_message(:step, from, s) do
      {:ok, line} = Tartarus.Agent.read(:robot, :line)
      {{l, r}, ctl} = s.pfa.control(line, 0.02, s.ctl)
      :ok = Tartarus.Agent.write(:robot, {:wheels, l, r})
      Tartarus.Agent.reply(from, :ok)
      {:stay, %{s | ctl: ctl}}
    end
  end

  setup do
    world =
      World.new(noise: :none)
      |> World.add_robot(:santa, x: 1.0, y: 1.0)
      |> World.add_robot(:claus, x: 1.0, y: 2.0, tool: :claws)

    arena = start_supervised!({Server, world: world})
    hosts = for n <- [:santa, :claus], do: :"arena_#{n}_#{System.unique_integer([:positive])}"

    for {h, robot} <- Enum.zip(hosts, [:santa, :claus]) do
      {:ok, _} = Tartarus.start_host(h)
      on_exit(fn -> Tartarus.stop_host(h) end)
      :ok = Tartarus.attach_plugin(h, :robot, {RobotPlugin, arena: arena, robot: robot})
    end

    %{arena: arena, hosts: hosts}
  end

  test "two robot hosts share one arena; agents drive and sense their own robot", %{
    arena: arena,
    hosts: [hs, hc]
  } do
    {:ok, a} = Tartarus.create_agent(hs, Driver, nil)
    {:ok, b} = Tartarus.create_agent(hc, Driver, nil)
    assert {:ok, {:ok, %{ultrasonic: us, colour: 7}}} = Tartarus.request(a, {:read, :all})
    assert us in 0..200
    assert Tartarus.request(a, {:write, {:wheels, 1.0, 1.0}}) == {:ok, :ok}
    assert Tartarus.request(b, {:write, {:wheels, -1.0, 1.0}}) == {:ok, :ok}
    :ok = Server.step(arena, 40)
    {x, y, _} = Server.pose(arena, :santa)
    assert_in_delta x, 1.2, 1.0e-9
    assert_in_delta y, 1.0, 1.0e-9
    {cx, _, th} = Server.pose(arena, :claus)
    assert_in_delta cx, 1.0, 1.0e-9
    assert_in_delta th, TartarusArena.Geometry.wrap_angle(0.8 * 0.5 / 0.11), 1.0e-9
    assert Tartarus.request(a, {:write, :stop}) == {:ok, :ok}
    assert Tartarus.request(a, {:read, :bogus}) == {:ok, {:error, {:bad_argument, :bogus}}}
    assert Tartarus.request(a, {:write, {:fly, 1}}) == {:ok, {:error, {:bad_argument, {:fly, 1}}}}
  end

  test "describe names the robot's capabilities; init checks its options", %{
    arena: arena,
    hosts: [hs, hc]
  } do
    assert [{:robot, %{kind: :robot, robot: :santa, capabilities: [:drive]}}] =
             Tartarus.plugins(hs)

    assert [{:robot, %{capabilities: [:drive, :claws]}}] = Tartarus.plugins(hc)
    assert RobotPlugin.init(arena: arena) == {:error, {:bad_option, :robot, "required"}}

    assert RobotPlugin.init(arena: arena, robot: :nobody) ==
             {:error, {:bad_option, :robot, "no such robot in the arena"}}
  end

  test "a camera plugin gives a PNG of the arena to agents on its host", %{
    arena: arena,
    hosts: [hs, _]
  } do
    :ok =
      Tartarus.attach_plugin(
        hs,
        :camera,
        {CameraPlugin, arena: arena, center: {1.0, 1.0}, view: 0.6, pixels: {60, 40}}
      )

    {:ok, a} = Tartarus.create_agent(hs, Driver, nil)
    {:ok, {:ok, png}} = Tartarus.request(a, :snapshot)
    assert {60, 40, rows} = PNG.decode(png)
    # the robot is at the centre of the view
    <<_::binary-size(30 * 3), r, g, b, _::binary>> = Enum.at(rows, 20)
    assert {r, g, b} in [{157, 183, 213}, {35, 52, 68}]
  end

  test "an agent carrying a PFA follows a line with its host's robot", %{
    arena: arena,
    hosts: [hs, _]
  } do
    :ok =
      Server.update(arena, fn w ->
        w
        |> World.add_line([{0.5, 1.0}, {1.5, 1.0}, {2.2, 1.4}])
        |> World.place(:santa, {0.9, 1.0, 0.2})
      end)

    {:ok, a} = Tartarus.create_agent(hs, Follower, TartarusArena.PFA.A4)

    for _ <- 1..300 do
      {:ok, :ok} = Tartarus.request(a, :step)
      :ok = Server.step(arena, 1)
    end

    {x, y, _} = Server.pose(arena, :santa)
    assert x > 1.55
    # on the second leg of the line (slope 0.4 / 0.7 from (1.5, 1.0))
    assert_in_delta y, 1.0 + (x - 1.5) * 0.4 / 0.7, 0.03
  end
end
