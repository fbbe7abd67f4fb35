defmodule TartarusArena.ServerTest do
  use ExUnit.Case, async: true

  import Tartarus.TestSupport

  alias TartarusArena.{Paths, PFA, Run, Server, World}

  test "with tick_ms the server steps the world by itself" do
    w = World.new(noise: :none) |> World.add_robot(:r, x: 1, y: 1)
    pid = start_supervised!({Server, world: w, tick_ms: 5})
    :ok = Server.set_wheels(pid, :r, 1.0, 1.0)
    # the ticks move the robot
    eventually(fn -> elem(Server.pose(pid, :r), 0) > 1.0 end)

    assert World.time(Server.world(pid)) > 0
  end

  test "sense of an unknown robot, a failing update and a bad start are errors, not crashes" do
    pid = start_supervised!({Server, world: World.new()})
    assert Server.sense(pid, :nobody) == {:error, {:no_such_robot, :nobody}}
    assert {:error, _} = Server.update(pid, fn w -> World.add_robot(w, :r, x: 0.0, y: 0.0) end)
    assert Server.world(pid).robots == %{}

    assert_raise ArgumentError, ~r/for key \[:world\]: expected a TartarusArena.World/, fn ->
      Server.start_link(world: :flat)
    end
  end

  test "a sub-path run from a given pose; same seed, same measure" do
    p = Paths.path(1, 2)
    sp = Enum.at(p.subpaths, 1)
    {x, y, th} = Paths.point_at(p, sp.from + 0.001)
    # 1.5 cm to the side of the line and 0.2 rad off its heading
    pose = {x - 0.015 * :math.sin(th), y + 0.015 * :math.cos(th), th + 0.2}
    a = Run.subpath(PFA.A4, p, 1, seed: 4, pose: pose)
    assert a.completed and a.type == :sp_a and a.pfa == "A4"
    assert a == Run.subpath(PFA.A4, p, 1, seed: 4, pose: pose)
  end
end
