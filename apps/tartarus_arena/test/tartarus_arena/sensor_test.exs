defmodule TartarusArena.SensorTest do
  use ExUnit.Case, async: true

  alias TartarusArena.World

  defp sense(w, id \\ :r), do: elem(World.sense(w, id), 0)

  defp facing_wall(d, opts \\ [noise: :none]) do
    # robot front (radius 0.07) at distance d from the right wall
    World.new(opts) |> World.add_robot(:r, x: 3.0 - 0.07 - d, y: 1.5)
  end

  test "ranges over random poses, with noise" do
    w =
      World.new(seed: 3, light: [on: true])
      |> World.add_puck(:p, x: 1.0, y: 1.0)
      |> World.add_line([{0.2, 0.2}, {2.8, 2.8}])

    {readings, _} =
      Enum.map_reduce(1..300, {w, Tartarus.Random.new(5)}, fn _, {w, rng} ->
        {[a, b, c], rng} =
          Enum.map_reduce(1..3, rng, fn _, rng -> Tartarus.Random.uniform(rng) end)

        w =
          World.add_robot(%{w | robots: %{}, order: []}, :r,
            x: 0.1 + 2.8 * a,
            y: 0.1 + 2.8 * b,
            theta: 6.3 * c
          )

        {s, w} = World.sense(w, :r)
        {s, {w, rng}}
      end)

    for s <- readings do
      assert s.ultrasonic in 0..200
      assert s.colour in 0..9
      assert elem(s.light, 0) in 0..100 and elem(s.light, 1) in 0..100
      assert elem(s.line, 0) in 0..100 and elem(s.line, 1) in 0..100
    end
  end

  test "ultrasonic: a closer obstacle gives a lower reading; far is capped at 200" do
    readings = for d <- [1.5, 1.0, 0.6, 0.3, 0.1, 0.02], do: sense(facing_wall(d)).ultrasonic
    assert readings == [150, 100, 60, 30, 10, 2]
    assert sense(World.new(noise: :none) |> World.add_robot(:r, x: 0.3, y: 1.5)).ultrasonic == 200

    # with noise, still monotone over gaps of 10 cm
    noisy = for d <- [1.0, 0.9, 0.8, 0.7, 0.6, 0.5], do: sense(facing_wall(d, seed: 2)).ultrasonic
    assert noisy == Enum.sort(noisy, :desc)
  end

  test "ultrasonic sees other robots and tall blocks, not low pucks" do
    base = World.new(noise: :none) |> World.add_robot(:r, x: 0.5, y: 1.5)
    assert sense(World.add_puck(base, :p, x: 1.5, y: 1.5)).ultrasonic == 200

    assert sense(World.add_puck(base, :b, x: 1.5, y: 1.5, tall: true, radius: 0.05)).ultrasonic ==
             88

    assert sense(World.add_robot(base, :o, x: 1.5, y: 1.5)).ultrasonic == 86
  end

  test "colour: floor 7, a yellow puck in the gripper 3, a marker its colour, a line 0" do
    base = World.new(noise: :none) |> World.add_robot(:r, x: 1.0, y: 1.5)
    assert sense(base).colour == 7
    assert sense(World.add_puck(base, :p, x: 1.1, y: 1.5)).colour == 3
    assert sense(World.add_marker(base, x: 1.1, y: 1.5, colour: 4)).colour == 4
    assert sense(World.add_line(base, [{1.095, 1.0}, {1.095, 2.0}])).colour == 0
  end

  test "colour noise: a misread with the given probability, from the seeded stream" do
    w =
      World.new(seed: 9, noise: %{colour: 0.3})
      |> World.add_robot(:r, x: 1.0, y: 1.5)
      |> World.add_puck(:p, x: 1.1, y: 1.5)

    {reads, _} = Enum.map_reduce(1..1000, w, fn _, w -> World.sense(w, :r, [:colour]) end)
    wrong = Enum.count(reads, &(&1.colour != 3))
    # 0.3 x 0.9 expected (a misread may draw 3): 270
    assert wrong > 200 and wrong < 340
    assert Enum.all?(reads, &(&1.colour in 0..9))
    {again, _} = Enum.map_reduce(1..1000, w, fn _, w -> World.sense(w, :r, [:colour]) end)
    assert again == reads
  end

  test "light: switching on and off; nearer is brighter; the side facing it reads more" do
    at = fn x, theta, state ->
      World.new(noise: :none, light: [x: 1.5, y: 1.5])
      |> World.set_light(state)
      |> World.add_robot(:r, x: x, y: 1.5, theta: theta)
      |> sense()
      |> Map.fetch!(:light)
    end

    assert at.(0.5, 0.0, :off) == {5, 5}
    {l_far, r_far} = at.(0.5, 0.0, :on)
    {l_near, r_near} = at.(1.2, 0.0, :on)
    assert l_near > l_far and r_near > r_far
    assert l_far == r_far
    # light on the robot's left: the left sensor reads more
    {l, r} = at.(0.8, -:math.pi() / 2, :on)
    assert l > r
    w = World.new(noise: :none) |> World.set_light(:on)
    assert World.light_on?(w)
    refute World.light_on?(World.set_light(w, :off))
  end

  describe "light sensor model" do
    # the light at (1.5, 1.5), the bulb 0.12 m above the sensors; raw (noiseless) readings
    defp raw(x, y, theta, side) do
      w =
        World.new(noise: :none, light: [x: 1.5, y: 1.5, on: true])
        |> World.add_robot(:r, x: x, y: y, theta: theta)

      World.light_raw(w, w.robots[:r], side)
    end

    test "hand-computed cases" do
      # facing the light from 0.5 m: r = 0.5, d = sqrt(0.25 + 0.0144), c = r / d, each
      # sensor 45 degrees off the bearing: f = 0.3 + 0.7 (1 - c (1 - (1 + cos 45) / 2)),
      # reading 5 + 95 f / (1 + (d / 0.5)^2)
      assert_in_delta raw(1.0, 1.5, 0.0, 1), 46.568, 0.001
      assert_in_delta raw(1.0, 1.5, 0.0, -1), 46.568, 0.001
      # right under the bulb: c = 0, f = 1, d = 0.12: 5 + 95 / 1.0576, whatever the heading
      assert_in_delta raw(1.5, 1.5, 0.0, 1), 94.826, 0.001
      assert_in_delta raw(1.5, 1.5, 2.0, -1), 94.826, 0.001
      # the light 0.5 m to the left: the left sensor faces it at 45 degrees, the right
      # one at 135 degrees
      assert_in_delta raw(1.5, 1.0, 0.0, 1), 46.568, 0.001
      assert_in_delta raw(1.5, 1.0, 0.0, -1), 24.346, 0.001
      # the light behind, 0.5 m: both at 135 degrees
      assert_in_delta raw(2.0, 1.5, 0.0, 1), 24.346, 0.001
      assert_in_delta raw(2.0, 1.5, 0.0, -1), 24.346, 0.001
      # off: ambient
      w = World.new(noise: :none) |> World.add_robot(:r, x: 1.5, y: 1.5)
      assert World.light_raw(w, w.robots[:r], 1) == 5.0
    end

    test "monotone along any straight approach to the light, for every heading" do
      for bearing <- Enum.map(0..11, &(&1 * :math.pi() / 6)),
          theta <- Enum.map(0..7, &(&1 * :math.pi() / 4)),
          side <- [1, -1] do
        readings =
          for k <- 140..0//-1 do
            d = k / 100
            raw(1.5 - d * :math.cos(bearing), 1.5 - d * :math.sin(bearing), theta, side)
          end

        assert readings == Enum.sort(readings), "bearing #{bearing}, theta #{theta}, #{side}"
        assert List.last(readings) > hd(readings) + 20
      end
    end

    test "the sensor facing the light reads more, wherever the light is to one side" do
      for deg <- Enum.map(1..35, &(&1 * 10)), deg != 180, r <- [0.05, 0.2, 0.5, 1.2] do
        a = deg * :math.pi() / 180
        # the robot heading 0 at distance r from the light, which is at bearing a
        {x, y} = {1.5 - r * :math.cos(a), 1.5 - r * :math.sin(a)}
        {left, right} = {raw(x, y, 0.0, 1), raw(x, y, 0.0, -1)}
        if deg < 180, do: assert(left > right), else: assert(right > left)
      end

      # ahead or behind: the same for both
      assert raw(1.0, 1.5, 0.0, 1) == raw(1.0, 1.5, 0.0, -1)
    end

    test "under the bulb beats facing it from any distance; integer readings in range" do
      under = raw(1.5, 1.5, 0.0, 1)

      for d <- [0.05, 0.1, 0.25, 0.5], theta <- [0.0, 1.0, 3.0], side <- [1, -1] do
        assert raw(1.5 - d, 1.5, theta, side) < under
      end

      w =
        World.new(noise: :none, light: [x: 1.5, y: 1.5, on: true])
        |> World.add_robot(:r, x: 1.5, y: 1.5)

      assert sense(w).light == {95, 95}
    end
  end

  test "line sensors straddle a line: white when centred, black on the side it drifts to" do
    line = fn y ->
      World.new(noise: :none)
      |> World.add_line([{0.5, 1.5}, {2.5, 1.5}])
      |> World.add_robot(:r, x: 1.0, y: y)
      |> sense()
      |> Map.fetch!(:line)
    end

    {l, r} = line.(1.5)
    assert l == r and l >= 50
    {l, r} = line.(1.475)
    assert l <= 15 and r == 60
    {l, r} = line.(1.525)
    assert r <= 15 and l == 60
    assert line.(1.0) == {60, 60}
  end
end
