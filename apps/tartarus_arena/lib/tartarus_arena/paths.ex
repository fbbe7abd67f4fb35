defmodule TartarusArena.Paths do
  @moduledoc """
  The two closed line paths of the thesis's path-following experiment (§6.5.11, Fig. 6.12),
  their sub-paths with the features of Table 6.3, and progress and lap tracking on them.

  A path is a closed black line built from turtle moves, cut into sub-paths of four types:

  | type | description | linearity | curvature | 90° | sharpness |
  |---|---|---|---|---|---|
  | `:sp_a` | curved path | 0.3 | 0.7 | 0 | 0.2 |
  | `:sp_b` | path with 90° turns | 0.5 | 0.3 | 0.9 | 0.7 |
  | `:sp_c` | straight path | 0.7 | 0.2 | 0 | 0 |
  | `:sp_d` | acute turns | 0.4 | 0.5 | 0.3 | 0.9 |

  Path 1 (`path(1, seed)`) is sp-c, sp-a, sp-b, sp-a in the lower half of a 3 m x 3 m arena;
  path 2 is sp-c, sp-a, sp-d, sp-b, sp-a in the upper half. Both run counter-clockwise.
  sp-b is a notch of four right-angle corners; sp-d two zigzags of 100-degree turns (80
  degrees inside: acute). As in the thesis, sub-paths of one type differ between instances:
  in shape (path 2's first curve has a longer straight between its bends, its last curve a
  tighter radius, its notch is shorter) and in their feature vectors, which are Table 6.3's
  values plus a uniform jitter in ±0.05 drawn from the seed (clipped to [0, 1]).

  Each path has a start/finish flag at arc length 0 (a coloured marker beside the line:
  green for path 1, blue for path 2). A lap is complete when a robot's tracked progress
  passes the flag again (`track/4`): progress is the arc length of the nearest point of the
  line, unwrapped along the way, so wandering back and forth near the flag is not a lap.
  While the robot is off the line (more than 5 cm from it) progress grows no faster than
  the robot moves, so cutting across from one leg of a zigzag to the next is not progress
  until the robot is back on the line; on the line, progress is again the nearest point's
  unwrapped arc length. (An earlier version capped it always: each corner a robot cut
  short left the progress behind the robot for good, about 0.5 m per lap of Path-2, so
  after a few laps the sub-path boundaries, and the PFA switches, were metres away from
  the sub-paths themselves.)

      iex> p = TartarusArena.Paths.path(1, 7)
      iex> Enum.map(p.subpaths, & &1.type)
      [:sp_c, :sp_a, :sp_b, :sp_a]
      iex> Float.round(p.length, 2)
      6.08
  """

  alias TartarusArena.Geometry, as: G

  @typedoc "A sub-path type."
  @type type :: :sp_a | :sp_b | :sp_c | :sp_d

  @typedoc "A sub-path instance: its type, index on the path, arc-length span, features."
  @type subpath :: %{
          index: non_neg_integer(),
          type: type(),
          from: float(),
          to: float(),
          features: [float()]
        }

  @typedoc "A closed path."
  @type t :: %{
          id: 1 | 2,
          points: [{float(), float()}],
          segs: tuple(),
          length: float(),
          subpaths: [subpath()],
          start: {float(), float(), float()},
          flag_colour: 0..9
        }

  @typedoc "A robot's progress on a path."
  @type tracker :: %{
          idx: non_neg_integer(),
          s: float(),
          progress: float(),
          along: float(),
          skipped: boolean(),
          laps: non_neg_integer()
        }

  # a robot this close to the line (m) is on it for the progress (`track/4`)
  @rejoin 0.05
  # the most of the path (m) a robot may skip between leaving the line and rejoining it
  # (cutting a corner short saves at most about 0.1 m here; skipping Path-2's notch 0.4 m)
  @max_skip 0.15

  @table %{
    sp_a: [0.3, 0.7, 0.0, 0.2],
    sp_b: [0.5, 0.3, 0.9, 0.7],
    sp_c: [0.7, 0.2, 0.0, 0.0],
    sp_d: [0.4, 0.5, 0.3, 0.9]
  }

  @doc """
  Table 6.3's feature vector `[linearity, curvature, ninety, sharpness]` of a sub-path type.

      iex> TartarusArena.Paths.table_features(:sp_b)
      [0.5, 0.3, 0.9, 0.7]
  """
  @spec table_features(type()) :: [float()]
  def table_features(type), do: Map.fetch!(@table, type)

  @doc "The four sub-path types."
  @spec types() :: [type()]
  def types, do: [:sp_a, :sp_b, :sp_c, :sp_d]

  @doc """
  Path 1 or 2 (see the moduledoc); `seed` fixes the features' jitter. Option
  `corner_radius` (m, default 0: sharp polygon tips): every corner of the line (a turn of
  more than 30 degrees at one vertex: the right angles of sp-b, the 100-degree turns of
  sp-d) is rounded into an arc of that radius tangent to both legs, as tape laid by hand
  is; the arcs of sp-a are already round. The sub-paths keep their types, features and
  ends.

      iex> sharp = TartarusArena.Paths.path(1, 7)
      iex> round = TartarusArena.Paths.path(1, 7, corner_radius: 0.05)
      iex> Float.round(sharp.length - round.length, 3)
      0.086
      iex> Enum.map(round.subpaths, & &1.type) == Enum.map(sharp.subpaths, & &1.type)
      true
  """
  @spec path(1 | 2, term(), keyword()) :: t()
  def path(id, seed, opts \\ [])

  def path(1, seed, opts) do
    build(1, seed, {0.9, 0.3, 0.0}, 2, Keyword.get(opts, :corner_radius, 0),
      sp_c: [straight: 1.5],
      sp_a: [arc: {0.3, 90}, straight: 0.3, arc: {0.3, 90}],
      sp_b: [
        straight: 0.5,
        corner: 90,
        straight: 0.3,
        corner: -90,
        straight: 0.6,
        corner: -90,
        straight: 0.3,
        corner: 90,
        straight: 0.4
      ],
      sp_a: [arc: {0.3, 90}, straight: 0.3, arc: {0.3, 90}]
    )
  end

  def path(2, seed, opts) do
    build(2, seed, {0.9, 1.6, 0.0}, 1, Keyword.get(opts, :corner_radius, 0),
      sp_c: [straight: 1.5],
      sp_a: [arc: {0.3, 90}, straight: 0.5, arc: {0.3, 90}],
      sp_d: [
        straight: 0.3,
        corner: 100,
        straight: 0.3,
        corner: -100,
        straight: 0.5,
        corner: 100,
        straight: 0.3,
        corner: -100,
        straight: 0.4
      ],
      sp_b: [
        straight: 0.1,
        corner: -90,
        straight: 0.2,
        corner: 90,
        straight: 0.15,
        corner: 90,
        straight: 0.2,
        corner: -90,
        to_x: 0.9
      ],
      sp_a: [arc: {0.22, 90}, to_y: 1.82, arc: {0.22, 90}]
    )
  end

  defp build(id, seed, {x0, y0, h0} = start, flag_colour, corner_radius, parts) do
    rng = Tartarus.Random.new({:paths, seed, id})

    {pts, subs, _pose, _rng, _i} =
      Enum.reduce(parts, {[{x0, y0}], [], start, rng, 0}, fn {type, moves},
                                                             {pts, subs, pose, rng, i} ->
        {pts, pose} = Enum.reduce(moves, {pts, pose}, &turtle/2)

        {features, rng} =
          Enum.map_reduce(Map.fetch!(@table, type), rng, fn f, rng ->
            {u, rng} = Tartarus.Random.uniform(rng)
            {min(1.0, max(0.0, Float.round(f + (u - 0.5) * 0.1, 3))), rng}
          end)

        {pts, [%{index: i, type: type, npts: length(pts), features: features} | subs], pose, rng,
         i + 1}
      end)

    [last | rest] = pts
    gap = G.dist(elem(last, 0), elem(last, 1), x0, y0)
    if gap > 1.0e-3, do: raise("path #{id} does not close (gap #{gap} m)")
    {points, at} = round_corners(Enum.reverse(rest), corner_radius)
    segs = segments(points)
    n = tuple_size(segs)
    length = elem(segs, n - 1) |> then(fn {_, _, _, _, s0, len} -> s0 + len end)

    {subpaths, _} =
      subs
      |> Enum.reverse()
      |> Enum.map_reduce(0.0, fn sp, from ->
        to =
          if sp.npts - 1 >= tuple_size(at),
            do: length,
            else: elem(elem(segs, elem(at, sp.npts - 1)), 4)

        {%{index: sp.index, type: sp.type, from: from, to: to, features: sp.features}, to}
      end)

    %{
      id: id,
      points: points,
      segs: segs,
      length: length,
      subpaths: subpaths,
      start: {x0, y0, h0},
      flag_colour: flag_colour
    }
  end

  # Rounds every corner (a turn of more than 30 degrees at a vertex) of the closed polygon
  # into an arc of radius r tangent to both legs; returns the points and, for each old
  # index, the new index of that point (a corner's: its arc's first point).
  defp round_corners(points, r) when r == 0,
    do: {points, List.to_tuple(Enum.to_list(0..(length(points) - 1)))}

  defp round_corners(points, r) do
    pts = List.to_tuple(points)
    n = tuple_size(pts)

    {new, at, _k} =
      Enum.reduce(0..(n - 1), {[], [], 0}, fn i, {acc, at, k} ->
        prev = elem(pts, Integer.mod(i - 1, n))
        here = elem(pts, i)
        next = elem(pts, Integer.mod(i + 1, n))
        arc = fillet(prev, here, next, r)
        {Enum.reverse(arc, acc), [k | at], k + length(arc)}
      end)

    {Enum.reverse(new), at |> Enum.reverse() |> List.to_tuple()}
  end

  # the arc replacing vertex `here` (or [here] when the turn there is 30 degrees or less)
  defp fillet({ax, ay}, {hx, hy} = here, {bx, by}, r) do
    h_in = :math.atan2(hy - ay, hx - ax)
    turn = G.wrap_angle(:math.atan2(by - hy, bx - hx) - h_in)

    if abs(turn) <= :math.pi() / 6 do
      [here]
    else
      t = r * :math.tan(abs(turn) / 2)

      if t > G.dist(ax, ay, hx, hy) / 2 or t > G.dist(hx, hy, bx, by) / 2,
        do:
          raise(ArgumentError, "corner radius #{r} m does not fit the corner at #{inspect(here)}")

      sign = if turn > 0, do: 1, else: -1
      {sx, sy} = {hx - t * :math.cos(h_in), hy - t * :math.sin(h_in)}
      cx = sx - sign * r * :math.sin(h_in)
      cy = sy + sign * r * :math.cos(h_in)
      steps = max(2, ceil(r * abs(turn) / 0.01))

      for k <- 0..steps do
        th = h_in + turn * k / steps
        {cx + sign * r * :math.sin(th), cy - sign * r * :math.cos(th)}
      end
    end
  end

  defp turtle({:straight, len}, {[{x, y} | _] = pts, {_, _, h}}) do
    p = {x + len * :math.cos(h), y + len * :math.sin(h)}
    {[p | pts], {elem(p, 0), elem(p, 1), h}}
  end

  # a straight along the current heading up to the line x = v (or y = v)
  defp turtle({:to_x, v}, {[{x, _} | _], {_, _, h}} = acc),
    do: turtle({:straight, (v - x) / :math.cos(h)}, acc)

  defp turtle({:to_y, v}, {[{_, y} | _], {_, _, h}} = acc),
    do: turtle({:straight, (v - y) / :math.sin(h)}, acc)

  defp turtle({:corner, deg}, {pts, {x, y, h}}), do: {pts, {x, y, h + deg * :math.pi() / 180}}

  defp turtle({:arc, {r, deg}}, {pts, {x, y, h}}) do
    sign = if deg >= 0, do: 1, else: -1
    total = abs(deg) * :math.pi() / 180
    n = max(2, ceil(r * total / 0.02))
    cx = x - sign * r * :math.sin(h)
    cy = y + sign * r * :math.cos(h)

    pts =
      Enum.reduce(1..n, pts, fn k, pts ->
        a = h + sign * total * k / n
        [{cx + sign * r * :math.sin(a), cy - sign * r * :math.cos(a)} | pts]
      end)

    hn = h + sign * total
    [{px, py} | _] = pts
    {pts, {px, py, hn}}
  end

  defp segments(points) do
    {segs, _} =
      (points ++ [hd(points)])
      |> Enum.chunk_every(2, 1, :discard)
      |> Enum.map_reduce(0.0, fn [{ax, ay}, {bx, by}], s0 ->
        len = G.dist(ax, ay, bx, by)
        {{ax, ay, bx, by, s0, len}, s0 + len}
      end)

    List.to_tuple(segs)
  end

  @doc "Paints a path's line and its start/finish flag on a world."
  @spec add_to(TartarusArena.World.t(), t()) :: TartarusArena.World.t()
  def add_to(world, path) do
    {x, y, h} = path.start

    world
    |> TartarusArena.World.add_line(path.points, closed: true)
    |> TartarusArena.World.add_marker(
      x: x - 0.09 * :math.sin(h),
      y: y + 0.09 * :math.cos(h),
      w: 0.06,
      h: 0.06,
      colour: path.flag_colour,
      label: "Path-#{path.id}"
    )
  end

  @doc """
  The nearest point of the path's line to `(x, y)`: `{arc_length, distance, segment_index}`.
  With `hint` (a segment index), only segments near it are searched (a robot moves little
  between two looks).

      iex> p = TartarusArena.Paths.path(1, 0)
      iex> {s, d, _} = TartarusArena.Paths.locate(p, 1.0, 0.32)
      iex> {Float.round(s, 3), Float.round(d, 3)}
      {0.1, 0.02}
  """
  @spec locate(t() | map(), float(), float(), non_neg_integer() | nil) ::
          {float(), float(), non_neg_integer()}
  def locate(path, x, y, hint \\ nil) do
    n = tuple_size(path.segs)

    if hint do
      nearest(path.segs, n, x, y, Integer.mod(hint - 2, n), 8, {0.0, :infinity, 0})
    else
      nearest(path.segs, n, x, y, 0, n, {0.0, :infinity, 0})
    end
  end

  defp nearest(_segs, _n, _x, _y, _i, 0, best), do: best

  defp nearest(segs, n, x, y, i, left, {_, bd, _} = best) do
    {ax, ay, bx, by, s0, len} = elem(segs, i)
    {d, t} = G.point_segment(x, y, {ax, ay, bx, by})
    best = if d < bd, do: {s0 + t * len, d, i}, else: best
    nearest(segs, n, x, y, if(i + 1 == n, do: 0, else: i + 1), left - 1, best)
  end

  @doc "The point and heading of the line at arc length `s` (wrapped): `{x, y, theta}`."
  @spec point_at(t(), float()) :: {float(), float(), float()}
  def point_at(path, s) do
    s = s - Float.floor(s / path.length) * path.length
    n = tuple_size(path.segs)

    i =
      Enum.find(0..(n - 1), n - 1, fn i ->
        {_, _, _, _, s0, len} = elem(path.segs, i)
        s < s0 + len
      end)

    {ax, ay, bx, by, s0, len} = elem(path.segs, i)
    t = if len > 0, do: (s - s0) / len, else: 0.0
    {ax + t * (bx - ax), ay + t * (by - ay), :math.atan2(by - ay, bx - ax)}
  end

  @doc "The sub-path at arc length `s` (wrapped)."
  @spec subpath_at(t(), float()) :: subpath()
  def subpath_at(path, s) do
    s = s - Float.floor(s / path.length) * path.length
    Enum.find(path.subpaths, List.last(path.subpaths), &(s >= &1.from and s < &1.to))
  end

  @doc """
  Starts tracking a robot at `(x, y)` on the path. Progress counts from there; a robot
  placed on the flag (arc length 0) completes its first lap when it comes back to it.
  """
  @spec track_new(t(), float(), float()) :: tracker()
  def track_new(path, x, y) do
    {s, _d, idx} = locate(path, x, y)
    s = if s > path.length - 0.01, do: 0.0, else: s

    %{
      idx: idx,
      s: s,
      progress: 0.0,
      along: 0.0,
      skipped: false,
      start: s,
      laps: 0,
      distance: 0.0,
      x: x,
      y: y
    }
  end

  @doc """
  The pose on the line at the tracker's progress (facing along the line) and the tracker
  of a robot put there: where an experimenter puts back a robot that took a shortcut
  (`skipped`).
  """
  @spec back_to_progress(tracker(), t()) :: {tracker(), {float(), float(), float()}}
  def back_to_progress(tr, path) do
    {x, y, _} = pose = point_at(path, tr.start + tr.progress)
    {s, _d, idx} = locate(path, x, y)

    {%{tr | idx: idx, s: s, along: tr.progress, skipped: false, distance: 0.0, x: x, y: y}, pose}
  end

  @doc """
  Updates a tracker with the robot's new position: returns the tracker and whether a lap
  was completed by this move. `tracker.distance` is the robot's distance from the line.
  """
  @spec track(tracker(), t(), float(), float()) :: {tracker(), boolean()}
  def track(tr, path, x, y) do
    {s, d, idx} = locate(path, x, y, tr.idx)
    l = path.length
    ds = s - tr.s
    ds = if ds > l / 2, do: ds - l, else: if(ds < -l / 2, do: ds + l, else: ds)
    # off the line, progress grows no faster than the robot moves (cutting across is not
    # progress while it is off the line); back on the line it is again the nearest point's
    # unwrapped arc length (`along`), so the progress never lags behind where the robot is
    # (a lag would shift every sub-path boundary), unless that skips more than @max_skip
    # of the path (a shortcut, not a cut corner): then it stays behind and `skipped` says
    # so (`TartarusArena.Run` puts the robot back, `back_to_progress/2`)
    along = tr.along + ds
    moved = G.dist(tr.x, tr.y, x, y) + 0.005
    capped = tr.progress + max(-moved, min(moved, ds))

    {progress, skipped} =
      cond do
        d > @rejoin -> {capped, false}
        along - capped <= @max_skip -> {along, false}
        true -> {capped, true}
      end

    laps = max(tr.laps, floor((tr.start + progress) / l))

    {%{
       tr
       | idx: idx,
         s: s,
         progress: progress,
         along: along,
         skipped: skipped,
         laps: laps,
         distance: d,
         x: x,
         y: y
     }, laps > tr.laps}
  end
end
