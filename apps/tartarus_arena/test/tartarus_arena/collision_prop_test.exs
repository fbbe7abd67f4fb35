defmodule TartarusArena.CollisionPropTest do
  use ExUnit.Case, async: true

  alias TartarusArena.{Geometry, World}
  alias TartarusTools.Prop

  @robots [:a, :b, :c]

  # Three robots (one with claws, one with a pusher), five pucks (two close together, one
  # near a corner), an interior wall; random wheel and grip commands with random step
  # lengths up to 0.4 s. After every step: no robot is closer to a wall than its radius or
  # outside the arena, no robot crossed a wall since the last step, no two robots overlap,
  # no puck is in a wall, no puck overlaps a puck or a robot.
  @tag :property
  test "property: whatever the commands, no robot passes through a wall or another robot" do
    wheel = :proper_types.float(-1.5, 1.5)
    grip = :proper_types.elements([nil, :open, :close])

    cmd =
      {:proper_types.elements(@robots), wheel, wheel, grip, :proper_types.integer(1, 20),
       :proper_types.float(0.01, 0.4)}

    gen = {:proper_types.integer(1, 1_000_000), :proper_types.list(cmd)}

    prop =
      :proper.forall(gen, fn {seed, cmds} ->
        Prop.safely(fn ->
          w0 =
            World.new(seed: seed, size: {2.0, 2.0}, walls: [{{1.0, 0.6}, {1.0, 1.4}}])
            |> World.add_robot(:a, x: 0.5, y: 1.0, tool: :claws)
            |> World.add_robot(:b, x: 1.5, y: 1.0, theta: 3.0, tool: :pusher)
            |> World.add_robot(:c, x: 1.0, y: 0.3, theta: 1.5)
            |> World.add_puck(:p1, x: 0.7, y: 1.0)
            |> World.add_puck(:p2, x: 1.3, y: 1.0)
            |> World.add_puck(:p3, x: 1.0, y: 1.6, tall: true, radius: 0.05)
            |> World.add_puck(:p4, x: 1.37, y: 1.02)
            |> World.add_puck(:p5, x: 1.94, y: 1.9)

          cmds
          |> Enum.take(40)
          |> Enum.reduce_while({w0, true}, fn {id, l, r, g, n, dt}, {w, true} ->
            c = if g, do: [wheels: {l, r}, grip: g], else: [wheels: {l, r}]

            {w, ok} =
              Enum.reduce_while(1..n, {w, true}, fn i, {w, true} ->
                w2 = World.step(w, if(i == 1, do: %{id => c}, else: %{}), dt)
                if sound?(w, w2), do: {:cont, {w2, true}}, else: {:halt, {w2, false}}
              end)

            if ok, do: {:cont, {w, true}}, else: {:halt, {w, false}}
          end)
          |> elem(1)
        end)
      end)

    assert Prop.check(prop, 300) == true
  end

  defp sound?(before, w) do
    {aw, ah} = w.size

    Enum.all?(w.robots, fn {id, r} ->
      b = before.robots[id]

      r.x >= r.radius - 1.0e-9 and r.y >= r.radius - 1.0e-9 and r.x <= aw - r.radius + 1.0e-9 and
        r.y <= ah - r.radius + 1.0e-9 and
        Enum.all?(w.walls, fn seg ->
          Geometry.dist_segment(r.x, r.y, seg) >= r.radius - 1.0e-9 and
            ((b.x == r.x and b.y == r.y) or not Geometry.segments_cross?(b.x, b.y, r.x, r.y, seg))
        end) and
        Enum.all?(w.robots, fn {oid, o} ->
          oid == id or Geometry.dist(r.x, r.y, o.x, o.y) >= r.radius + o.radius - 1.0e-9
        end)
    end) and
      Enum.all?(w.pucks, fn {pid, p} ->
        Enum.all?(w.walls, &(Geometry.dist_segment(p.x, p.y, &1) >= p.radius - 1.0e-9)) and
          Enum.all?(w.pucks, fn {qid, q} ->
            qid == pid or Geometry.dist(p.x, p.y, q.x, q.y) >= p.radius + q.radius - 1.0e-6
          end) and
          Enum.all?(w.robots, fn {_, r} ->
            Geometry.dist(p.x, p.y, r.x, r.y) >= p.radius + r.radius - 1.0e-6
          end)
      end)
  end
end
