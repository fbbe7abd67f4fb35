defmodule TartarusArena.RenderTest do
  use ExUnit.Case, async: true

  alias TartarusArena.{PNG, Render, World}

  test "PNG round trip; a wrong row size is refused" do
    rows = [<<1, 2, 3, 4, 5, 6>>, <<7, 8, 9, 10, 11, 12>>]
    assert PNG.decode(PNG.encode(2, 2, rows)) == {2, 2, rows}

    assert_raise ArgumentError, ~r/expected 6 bytes, got: 3/, fn ->
      PNG.encode(2, 1, [<<1, 2, 3>>])
    end
  end

  test "camera PNG shows a yellow puck, the line and the floor where they are" do
    w =
      World.new()
      |> World.add_puck(:p, x: 1.5, y: 1.5, radius: 0.05)
      |> World.add_line([{1.0, 1.292}, {2.0, 1.292}])

    {40, 40, rows} = PNG.decode(Render.png(w, center: {1.5, 1.5}, view: 0.8, pixels: {40, 40}))
    px = fn i, j -> rows |> Enum.at(j) |> binary_part(i * 3, 3) end
    assert px.(20, 20) == <<0xF2, 0xC4, 0x18>>
    # row 30 is 1.29 m high, on the line
    assert px.(5, 30) == <<17, 17, 17>>
    assert px.(5, 5) == <<0xE6, 0xE2, 0xD8>>
  end

  test "SVG snapshot and trajectory plot are standalone documents with the arena's objects" do
    w =
      TartarusArena.paths_world(1)
      |> World.add_robot(:r1, x: 0.9, y: 0.3)
      |> World.add_puck(:p, x: 2.0, y: 2.0)
      |> World.set_light(:on)

    svg = Render.svg(w)
    assert svg =~ "<title>arena at t = 0.0 s</title>"
    assert svg =~ "Path-1" and svg =~ "Path-2"
    assert svg =~ "#fff35c"
    t = Render.trajectories(w, %{"r1 <A4>" => [{0.0, 0.9, 0.3}, {0.1, 1.0, 0.3}]}, title: "laps")
    assert t =~ "r1 &lt;A4&gt;" and t =~ "<polyline"
  end

  test "a pinhole camera on a robot sees a green block ahead, the floor below, the wall beyond" do
    w =
      World.new()
      |> World.add_robot(:santa, x: 1.0, y: 1.5)
      |> World.add_puck(:block, x: 1.4, y: 1.5, radius: 0.05, colour: 2, tall: true)

    {40, 30, rows} = PNG.decode(Render.camera_png(w, robot: :santa, pixels: {40, 30}))
    px = fn i, j -> rows |> Enum.at(j) |> binary_part(i * 3, 3) end
    # the block's side: green (#3aa845) shaded to 0.75
    assert px.(20, 15) == <<44, 126, 52>>
    # the floor at the bottom edge, the wall (grey) or sky at the top
    assert px.(20, 29) == <<0xE6, 0xE2, 0xD8>>
    assert px.(2, 0) in [<<90, 90, 96>>, <<200, 210, 220>>]
  end
end
