defmodule TartarusArena.WorldTest do
  use ExUnit.Case, async: true

  alias TartarusArena.World

  defp world(opts \\ []), do: World.new(Keyword.merge([noise: :none, seed: 1], opts))

  defp run(w, cmds, n, dt \\ 0.02),
    do: Enum.reduce(1..n, w, fn _, w -> World.step(w, cmds, dt) end)

  describe "kinematics" do
    test "straight line: both wheels at top speed for 2 s cover 0.5 m" do
      w = world() |> World.add_robot(:r, x: 0.5, y: 1.0, theta: 0.0) |> run(%{r: {1, 1}}, 100)
      {x, y, th} = World.pose(w, :r)
      assert_in_delta x, 1.0, 1.0e-9
      assert_in_delta y, 1.0, 1.0e-9
      assert_in_delta th, 0.0, 1.0e-9
      assert_in_delta World.time(w), 2.0, 1.0e-9
    end

    test "turn in place: opposite wheels keep the centre and turn at 2 v / axle" do
      w = world() |> World.add_robot(:r, x: 1.0, y: 1.0) |> run(%{r: {-0.5, 0.5}}, 10)
      {x, y, th} = World.pose(w, :r)
      assert_in_delta x, 1.0, 1.0e-12
      assert_in_delta y, 1.0, 1.0e-12
      # omega = (0.125 - -0.125) / 0.11 rad/s for 0.2 s
      assert_in_delta th, 0.25 / 0.11 * 0.2, 1.0e-9
    end

    test "an arc stays on its circle (midpoint rule: within 0.01 mm after 4 s)" do
      w = world() |> World.add_robot(:r, x: 1.5, y: 1.0) |> run(%{r: {0.5, 1.0}}, 200)
      # v = 0.1875, omega = 0.125 / 0.11: radius v / omega, centre straight left of the start
      radius = 0.1875 / (0.125 / 0.11)
      {x, y, _} = World.pose(w, :r)
      assert_in_delta :math.sqrt((x - 1.5) ** 2 + (y - (1.0 + radius)) ** 2), radius, 1.0e-5
    end

    test "speed limits: commands beyond [-1, 1] are clipped" do
      a = world() |> World.add_robot(:r, x: 0.5, y: 1.0) |> run(%{r: {5.0, 5.0}}, 50)
      b = world() |> World.add_robot(:r, x: 0.5, y: 1.0) |> run(%{r: {1.0, 1.0}}, 50)
      assert World.pose(a, :r) == World.pose(b, :r)
      c = world() |> World.add_robot(:r, x: 1.5, y: 1.0, max_speed: 0.1) |> run(%{r: {1, 1}}, 50)
      assert_in_delta elem(World.pose(c, :r), 0), 1.6, 1.0e-9
    end

    test "wheel noise is seeded: same seed, same pose; another seed, another pose" do
      go = fn seed ->
        World.new(seed: seed)
        |> World.add_robot(:r, x: 0.5, y: 1.0)
        |> run(%{r: {1, 0.8}}, 200)
        |> World.pose(:r)
      end

      assert go.(7) == go.(7)
      refute go.(7) == go.(8)
    end

    test "a long step is cut into sub-steps (same end as small steps, noise off)" do
      a = world() |> World.add_robot(:r, x: 0.5, y: 1.0) |> run(%{r: {1, 1}}, 1, 1.0)
      assert_in_delta elem(World.pose(a, :r), 0), 0.75, 1.0e-9
    end
  end

  describe "collisions" do
    test "a robot driving into a wall stops at the wall and is bumped" do
      w = world() |> World.add_robot(:r, x: 2.5, y: 1.0) |> run(%{r: {1, 1}}, 300)
      {x, _, _} = World.pose(w, :r)
      assert x <= 3.0 - 0.07
      assert x > 3.0 - 0.07 - 0.01
      assert w.robots.r.bumped
    end

    test "an interior wall is not crossed, even with steps longer than the robot" do
      w =
        world(walls: [{{1.5, 0.0}, {1.5, 3.0}}])
        |> World.add_robot(:r, x: 1.2, y: 1.0)
        |> run(%{r: {1, 1}}, 20, 0.5)

      assert elem(World.pose(w, :r), 0) <= 1.5 - 0.07
    end

    test "two robots driving head-on do not overlap" do
      w =
        world()
        |> World.add_robot(:a, x: 1.0, y: 1.0, theta: 0.0)
        |> World.add_robot(:b, x: 2.0, y: 1.0, theta: :math.pi())
        |> run(%{a: {1, 1}, b: {1, 1}}, 300)

      {ax, _, _} = World.pose(w, :a)
      {bx, _, _} = World.pose(w, :b)
      assert bx - ax >= 0.14 - 1.0e-9
    end

    test "bad options are refused with the key, the expectation and the value" do
      assert_raise ArgumentError,
                   "invalid options given to TartarusArena.World.add_robot/3 for key :tool: expected one of [:none, :pusher, :claws], got: :wings",
                   fn -> world() |> World.add_robot(:r, x: 1, y: 1, tool: :wings) end

      assert_raise ArgumentError,
                   ~r/World.new\/1 for key :size: expected \{width, height\} in metres, both positive, got: \{0, 2\}/,
                   fn ->
                     World.new(size: {0, 2})
                   end

      assert_raise ArgumentError, ~r/add_puck\/3 for key :colour/, fn ->
        world() |> World.add_puck(:p, x: 1, y: 1, colour: 12)
      end
    end

    test "adding a robot inside a wall is refused" do
      assert_raise ArgumentError, ~r/overlaps/, fn ->
        world() |> World.add_robot(:r, x: 0.01, y: 1)
      end
    end
  end

  describe "pucks" do
    test "a robot pushes a free puck ahead of it" do
      w =
        world()
        |> World.add_robot(:r, x: 1.0, y: 1.0)
        |> World.add_puck(:p, x: 1.2, y: 1.0)
        |> run(%{r: {1, 1}}, 100)

      assert w.pucks.p.x > 1.4
      {x, _, _} = World.pose(w, :r)
      assert_in_delta w.pucks.p.x - x, 0.1, 0.002
    end

    test "a puck pushed into a wall stops there, and so does the robot" do
      w =
        world()
        |> World.add_robot(:r, x: 2.6, y: 1.0)
        |> World.add_puck(:p, x: 2.8, y: 1.0)
        |> run(%{r: {1, 1}}, 200)

      assert w.pucks.p.x <= 3.0 - 0.03
      {x, _, _} = World.pose(w, :r)
      assert x <= w.pucks.p.x - 0.1 + 1.0e-6
      assert w.robots.r.bumped
    end

    test "a puck pushed into a wall at an angle slides along it, and the robot goes on" do
      # the robot heads 45 degrees into the right wall (x = 3) with a puck in its pusher
      w =
        world()
        |> World.add_robot(:r, x: 2.75, y: 1.0, theta: :math.pi() / 4, tool: :pusher)
        |> World.add_puck(:p,
          x: 2.75 + 0.101 * :math.cos(:math.pi() / 4),
          y: 1.0 + 0.101 * :math.sin(:math.pi() / 4)
        )

      w = run(w, %{r: {1, 1}}, 100)
      p = w.pucks.p
      {x, y, _} = World.pose(w, :r)
      # the puck touches the wall and has slid up along it; the robot followed it until its
      # own body met the wall
      assert_in_delta p.x, 3.0 - 0.03, 0.001
      assert p.y > 1.25
      assert y > 1.15
      assert_in_delta x, 3.0 - 0.07, 0.01
      assert :math.sqrt((p.x - x) ** 2 + (p.y - y) ** 2) >= 0.1 - 1.0e-6
    end

    test "a puck pushed into another pushes it along" do
      w =
        world()
        |> World.add_robot(:r, x: 1.0, y: 1.0)
        |> World.add_puck(:p, x: 1.2, y: 1.0)
        |> World.add_puck(:q, x: 1.3, y: 1.0)
        |> run(%{r: {1, 1}}, 100)

      {x, _, _} = World.pose(w, :r)
      assert x > 1.4
      assert_in_delta w.pucks.q.x - w.pucks.p.x, 0.06, 0.001

      assert :math.sqrt((w.pucks.q.x - w.pucks.p.x) ** 2 + (w.pucks.q.y - w.pucks.p.y) ** 2) >=
               0.06 - 1.0e-6

      refute w.robots.r.bumped
    end

    test "a pusher whose puck is jammed in a corner can still turn in place, leaving the puck there" do
      # facing the corner (3, 3) with the puck wedged into it
      th = :math.pi() / 4
      px = 3.0 - 0.03 - 0.001

      w =
        world()
        |> World.add_robot(:r,
          x: px - 0.1005 * :math.cos(th),
          y: px - 0.1005 * :math.sin(th),
          theta: th,
          tool: :pusher
        )
        |> World.add_puck(:p, x: px, y: px)

      pushed = run(w, %{r: {1, 1}}, 20)
      {x, y, _} = World.pose(pushed, :r)
      assert_in_delta x, px - 0.1005 * :math.cos(th), 0.002
      assert_in_delta y, px - 0.1005 * :math.sin(th), 0.002
      assert pushed.robots.r.bumped
      turned = run(pushed, %{r: {0.2, 1}}, 50)
      {_, _, th2} = World.pose(turned, :r)
      assert abs(TartarusArena.Geometry.wrap_angle(th2 - th)) > 1.0
      # the puck stays in its corner (nudged at most along a wall), out of the gripper
      assert_in_delta turned.pucks.p.x, px, 0.005
      assert_in_delta turned.pucks.p.y, px, 0.005
      assert turned.pucks.p.x <= 3.0 - 0.03 and turned.pucks.p.y <= 3.0 - 0.03
      refute elem(World.sense(turned, :r), 0).puck_in_gripper
    end

    test "claws hold a puck when closed (it follows backwards) and drop it when opened" do
      w =
        world()
        |> World.add_robot(:c, x: 1.0, y: 1.0, tool: :claws)
        |> World.add_puck(:p, x: 1.102, y: 1.0)
        |> World.step(%{c: [grip: :close]}, 0.02)

      assert w.robots.c.held == :p
      {s, _} = World.sense(w, :c)
      assert s.holding == :p and s.puck_in_gripper
      w = run(w, %{c: {-1, -1}}, 40)
      {x, _, _} = World.pose(w, :c)
      assert x < 0.85
      assert_in_delta w.pucks.p.x - x, 0.102, 0.001
      w = w |> World.grip(:c, :open) |> run(%{c: {-1, -1}}, 20)
      assert w.pucks.p.x - elem(World.pose(w, :c), 0) > 0.2
    end

    test "a robot without claws cannot grip" do
      w =
        world()
        |> World.add_robot(:r, x: 1.0, y: 1.0)
        |> World.add_puck(:p, x: 1.102, y: 1.0)
        |> World.grip(:r, :close)

      assert w.robots.r.held == nil
    end

    test "a pusher keeps the puck in front while turning, and leaves it when backing off" do
      w =
        world()
        |> World.add_robot(:r, x: 1.0, y: 1.0, tool: :pusher)
        |> World.add_puck(:p, x: 1.101, y: 1.0)
        |> run(%{r: {0.3, 1.0}}, 100)

      {x, y, th} = World.pose(w, :r)
      bearing = :math.atan2(w.pucks.p.y - y, w.pucks.p.x - x)
      assert abs(TartarusArena.Geometry.wrap_angle(bearing - th)) < 0.2
      assert_in_delta :math.sqrt((w.pucks.p.x - x) ** 2 + (w.pucks.p.y - y) ** 2), 0.101, 0.002
      before = {w.pucks.p.x, w.pucks.p.y}
      w = run(w, %{r: {-1, -1}}, 20)
      assert {w.pucks.p.x, w.pucks.p.y} == before
    end
  end
end
