defmodule TartarusArena.Geometry do
  @moduledoc false
  # Plane geometry on floats: points are {x, y}, segments {ax, ay, bx, by}. Metres.

  @doc false
  # Distance from (px, py) to the segment, and the segment parameter t in [0, 1].
  def point_segment(px, py, {ax, ay, bx, by}) do
    dx = bx - ax
    dy = by - ay
    len2 = dx * dx + dy * dy

    t =
      if len2 == 0.0,
        do: 0.0,
        else: min(1.0, max(0.0, ((px - ax) * dx + (py - ay) * dy) / len2))

    cx = ax + t * dx
    cy = ay + t * dy
    {:math.sqrt((px - cx) * (px - cx) + (py - cy) * (py - cy)), t}
  end

  @doc false
  def dist_segment(px, py, seg), do: elem(point_segment(px, py, seg), 0)

  @doc false
  # True if the segments (p1, p2) and the wall segment intersect (touching counts).
  def segments_cross?(x1, y1, x2, y2, {ax, ay, bx, by}) do
    d1 = orient(ax, ay, bx, by, x1, y1)
    d2 = orient(ax, ay, bx, by, x2, y2)
    d3 = orient(x1, y1, x2, y2, ax, ay)
    d4 = orient(x1, y1, x2, y2, bx, by)

    cond do
      d1 * d2 < 0 and d3 * d4 < 0 -> true
      d1 == 0 and on_segment?(ax, ay, bx, by, x1, y1) -> true
      d2 == 0 and on_segment?(ax, ay, bx, by, x2, y2) -> true
      d3 == 0 and on_segment?(x1, y1, x2, y2, ax, ay) -> true
      d4 == 0 and on_segment?(x1, y1, x2, y2, bx, by) -> true
      true -> false
    end
  end

  defp orient(ax, ay, bx, by, px, py), do: (bx - ax) * (py - ay) - (by - ay) * (px - ax)

  defp on_segment?(ax, ay, bx, by, px, py) do
    px >= min(ax, bx) and px <= max(ax, bx) and py >= min(ay, by) and py <= max(ay, by)
  end

  @doc false
  # Distance along the ray (ox, oy) + t (dx, dy) (unit direction) to the segment, or nil.
  def ray_segment(ox, oy, dx, dy, {ax, ay, bx, by}) do
    ex = bx - ax
    ey = by - ay
    den = dx * ey - dy * ex

    if abs(den) < 1.0e-12 do
      nil
    else
      t = ((ax - ox) * ey - (ay - oy) * ex) / den
      u = ((ax - ox) * dy - (ay - oy) * dx) / den
      if t >= 0.0 and u >= 0.0 and u <= 1.0, do: t, else: nil
    end
  end

  @doc false
  # Distance along the ray (unit direction) to the circle, or nil (0.0 if inside).
  def ray_circle(ox, oy, dx, dy, cx, cy, r) do
    fx = ox - cx
    fy = oy - cy
    b = fx * dx + fy * dy
    c = fx * fx + fy * fy - r * r

    cond do
      c <= 0.0 ->
        0.0

      b > 0.0 ->
        nil

      true ->
        disc = b * b - c
        if disc < 0.0, do: nil, else: -b - :math.sqrt(disc)
    end
  end

  @doc false
  def dist(x1, y1, x2, y2), do: :math.sqrt((x1 - x2) * (x1 - x2) + (y1 - y2) * (y1 - y2))

  @doc false
  def wrap_angle(a) do
    a = :math.fmod(a + :math.pi(), 2 * :math.pi())
    if a < 0, do: a + :math.pi(), else: a - :math.pi()
  end
end
