defmodule TartarusArena.Render do
  @moduledoc """
  Pictures of an arena: an SVG snapshot (`svg/2`), an SVG trajectory plot (`trajectories/3`),
  a PNG as a camera looking straight down on part of the arena would take it (`png/2`), and
  a PNG through a pinhole camera on a pole or on a robot (`camera_png/2`).
  The SVGs are `TartarusTools.SVG.plan/2` plans in metres, with a scale bar.
  The floor is drawn in its colours (`TartarusArena.World.colour_hex/1`), lines black,
  pucks in their colours, the light as a yellow disc (grey when off), robots as discs with
  a heading mark and their id.
  """

  alias TartarusArena.World

  @palette ~w(#4e79a7 #f28e2b #e15759 #76b7b2 #59a14f #edc948 #b07aa1 #ff9da7 #9c755f #bab0ac)

  @doc """
  An SVG snapshot of the world (`TartarusTools.SVG.plan/2`, in metres with a scale bar):
  the floor, its lines and labelled markers, walls (inner walls labelled "wall"), the light
  ("light (on)" / "light (off)"), pucks labelled by id ("block" for tall ones) and robots
  with a heading mark and their id. Options: `:title` (default "arena at t = ... s"),
  `:subtitle` (the parameters and seed of the run), `:note`, `:width` (pixels, default
  720).

      iex> w = TartarusArena.World.new() |> TartarusArena.World.add_robot(:r1, x: 1, y: 1)
      iex> svg = TartarusArena.Render.svg(w)
      iex> String.starts_with?(svg, "<?xml") and svg =~ "r1" and svg =~ ~s(data-unit="m")
      true
  """
  @spec svg(World.t(), keyword()) :: binary()
  def svg(world, opts \\ []) do
    title = Keyword.get(opts, :title, "arena at t = #{Float.round(world.time, 2)} s")
    plan(world, opts, title, background(world) ++ robots(world), [])
  end

  @doc """
  An SVG of robots' trajectories over the arena's floor: `trajectories` maps a label to a
  list of `{t, x, y}` (as `TartarusArena.Run.laps/3` returns), each drawn in its colour
  (named in the legend) from a start disc to an end square, over the objects of `svg/2`
  (robots left out). Options as `svg/2`. Each trajectory is a
  `<polyline class="trajectory" data-name=".." data-samples="n">`.
  """
  @spec trajectories(World.t(), %{term() => [{number(), number(), number()}]}, keyword()) ::
          binary()
  def trajectories(world, trajs, opts \\ []) do
    drawn =
      trajs
      |> Enum.sort_by(&inspect(elem(&1, 0)))
      |> Enum.reject(fn {_, pts} -> pts == [] end)
      |> Enum.with_index()

    lines =
      Enum.flat_map(drawn, fn {{label, pts}, i} ->
        colour = Enum.at(@palette, rem(i, length(@palette)))
        {_, x0, y0} = hd(pts)
        {_, x1, y1} = List.last(pts)
        xy = Enum.map(pts, fn {_t, x, y} -> {x, y} end)
        xy = if length(xy) == 1, do: xy ++ xy, else: xy

        [
          %{
            shape: :line,
            points: xy,
            width_px: 1.5,
            stroke: colour,
            opacity: 0.85,
            class: "trajectory",
            data: %{name: label_text(label), samples: length(pts)},
            title: label_text(label)
          },
          %{
            shape: :marker,
            kind: :start,
            x: x0,
            y: y0,
            fill: colour,
            title: "start: #{label_text(label)}"
          },
          %{
            shape: :marker,
            kind: :end,
            x: x1,
            y: y1,
            fill: colour,
            title: "end: #{label_text(label)}"
          }
        ]
      end)

    legend =
      Enum.map(drawn, fn {{label, _}, i} ->
        {label_text(label), Enum.at(@palette, rem(i, length(@palette))), :line}
      end) ++ [{"start", "#ffffff", :start}, {"end", "#ffffff", :end}]

    plan(
      world,
      opts,
      Keyword.get(opts, :title, "trajectories"),
      background(world) ++ lines,
      legend
    )
  end

  defp label_text(label) when is_binary(label), do: label
  defp label_text(label) when is_atom(label) or is_number(label), do: to_string(label)
  defp label_text(label), do: inspect(label)

  defp plan(world, opts, title, shapes, legend) do
    {w, h} = world.size

    TartarusTools.SVG.plan(shapes,
      title: title,
      subtitle: Keyword.get(opts, :subtitle),
      note: Keyword.get(opts, :note),
      width: Keyword.get(opts, :width, 720),
      bounds: {0, 0, w, h},
      unit: "m",
      legend: legend
    )
  end

  defp background(world) do
    {w, h} = world.size
    pucks = Enum.sort_by(world.pucks, &inspect(elem(&1, 0)))
    labels = puck_labels(pucks)

    [%{shape: :rect, x: 0, y: 0, w: w, h: h, fill: World.colour_hex(7), class: "floor"}] ++
      for m <- world.markers do
        %{
          shape: :rect,
          x: m.x - m.w / 2,
          y: m.y - m.h / 2,
          w: m.w,
          h: m.h,
          fill: World.colour_hex(m.colour),
          label: m.label,
          class: "marker"
        }
      end ++
      for l <- world.lines, length(l.points) >= 2 do
        %{shape: :line, points: l.points, width: l.width, stroke: "#111", class: "line"}
      end ++
      for {x1, y1, x2, y2} <- world.walls do
        inner? = not border?({x1, y1, x2, y2}, w, h)

        %{
          shape: :line,
          points: [{x1, y1}, {x2, y2}],
          width_px: 4,
          stroke: "#444",
          class: if(inner?, do: "wall obstacle", else: "wall"),
          label: if(inner?, do: "wall")
        }
      end ++
      [
        %{
          shape: :circle,
          x: world.light.x,
          y: world.light.y,
          r: 0.05,
          fill: if(world.light.on, do: "#fff35c", else: "#999"),
          stroke: "#555",
          class: "light",
          label: if(world.light.on, do: "light (on)", else: "light (off)")
        }
      ] ++
      for {id, p} <- pucks do
        %{
          shape: :circle,
          x: p.x,
          y: p.y,
          r: p.radius,
          fill: World.colour_hex(p.colour),
          stroke: "#333",
          class: if(p.tall, do: "puck obstacle", else: "puck"),
          data: %{id: label_text(id)},
          title: puck_name(id, p),
          label: labels[id]
        }
      end
  end

  # A label per puck, or one per cluster of pucks closer than 0.2 m to each other (the
  # first of them: "pucks p1-p6"), so that labels do not overprint; blocks (tall) alone.
  defp puck_labels(pucks) do
    {clusters, _} =
      Enum.reduce(pucks, {[], MapSet.new()}, fn {id, _} = first, {acc, seen} ->
        if MapSet.member?(seen, id) do
          {acc, seen}
        else
          members = cluster([first], pucks, [first])
          {[members | acc], Enum.reduce(members, seen, &MapSet.put(&2, elem(&1, 0)))}
        end
      end)

    Map.new(Enum.reverse(clusters), fn
      [{id, p}] ->
        {id, puck_name(id, p)}

      [{id, _} | _] = ms ->
        ids = Enum.map(ms, &label_text(elem(&1, 0)))
        {id, "#{length(ms)} pucks #{hd(ids)}-#{List.last(ids)}"}
    end)
  end

  # "puck p3", "block b1"; a puck whose id says what it is already, as the roadblock's
  # `:block`, is named once ("block", not "block block").
  defp puck_name(id, p) do
    kind = if p.tall, do: "block", else: "puck"
    text = label_text(id)
    if text == kind, do: kind, else: "#{kind} #{text}"
  end

  defp cluster([], _pucks, acc), do: Enum.sort_by(acc, &inspect(elem(&1, 0)))

  defp cluster([{_, p} | rest], pucks, acc) do
    near =
      for {_, q} = e <- pucks,
          not q.tall and not p.tall,
          e not in acc,
          :math.sqrt((p.x - q.x) * (p.x - q.x) + (p.y - q.y) * (p.y - q.y)) < 0.2,
          do: e

    cluster(rest ++ near, pucks, acc ++ near)
  end

  defp border?({x1, y1, x2, y2}, w, h) do
    on = fn a, b, v -> abs(a - v) < 1.0e-6 and abs(b - v) < 1.0e-6 end
    on.(x1, x2, 0) or on.(x1, x2, w) or on.(y1, y2, 0) or on.(y1, y2, h)
  end

  defp robots(world) do
    for {id, r} <- Enum.sort_by(world.robots, &inspect(elem(&1, 0))),
        shape <- [
          %{
            shape: :circle,
            x: r.x,
            y: r.y,
            r: r.radius,
            fill: "#9db7d5",
            stroke: "#234",
            opacity: 0.9,
            class: "robot",
            data: %{id: label_text(id)},
            label: label_text(id),
            label_below: true
          },
          %{
            shape: :line,
            points: [
              {r.x, r.y},
              {r.x + r.radius * :math.cos(r.theta), r.y + r.radius * :math.sin(r.theta)}
            ],
            width_px: 2,
            stroke: "#234"
          }
        ],
        do: shape
  end

  @doc """
  A PNG (binary) of the arena seen from above by a camera: `:center` `{x, y}` (default
  the arena's centre), `:view` (width of the view in metres, default 1.0), `:pixels`
  `{width, height}` (default `{160, 120}`; the view's height follows the aspect ratio).

      iex> w = TartarusArena.World.new() |> TartarusArena.World.add_robot(:r1, x: 1.5, y: 1.5)
      iex> TartarusArena.PNG.size(TartarusArena.Render.png(w, pixels: {32, 24}))
      {32, 24}
  """
  @spec png(World.t(), keyword()) :: binary()
  def png(world, opts \\ []) do
    {aw, ah} = world.size
    {cx, cy} = Keyword.get(opts, :center, {aw / 2, ah / 2})
    view = Keyword.get(opts, :view, 1.0)
    {pw, ph} = Keyword.get(opts, :pixels, {160, 120})
    m = view / pw
    x0 = cx - view / 2
    y0 = cy + ph * m / 2
    pucks = Map.values(world.pucks)
    robots = Map.values(world.robots)

    rows =
      for j <- 0..(ph - 1) do
        y = y0 - (j + 0.5) * m

        for i <- 0..(pw - 1), into: <<>> do
          x = x0 + (i + 0.5) * m
          {r, g, b} = pixel(world, x, y, pucks, robots, m)
          <<r, g, b>>
        end
      end

    TartarusArena.PNG.encode(pw, ph, rows)
  end

  defp pixel(world, x, y, pucks, robots, m) do
    {aw, ah} = world.size
    l = world.light

    cond do
      x < 0 or y < 0 or x > aw or y > ah ->
        {60, 60, 60}

      Enum.any?(world.walls, &(TartarusArena.Geometry.dist_segment(x, y, &1) < max(m, 0.01))) ->
        {70, 70, 70}

      r = Enum.find(robots, &(dd(x, y, &1.x, &1.y) <= &1.radius)) ->
        hx = r.x + r.radius * 0.7 * :math.cos(r.theta)
        hy = r.y + r.radius * 0.7 * :math.sin(r.theta)
        if dd(x, y, hx, hy) < r.radius * 0.25, do: {35, 52, 68}, else: {157, 183, 213}

      p = Enum.find(pucks, &(dd(x, y, &1.x, &1.y) <= &1.radius)) ->
        rgb(World.colour_hex(p.colour))

      dd(x, y, l.x, l.y) <= 0.05 ->
        if l.on, do: {255, 243, 92}, else: {150, 150, 150}

      mk = World.marker_at(world, x, y) ->
        rgb(World.colour_hex(mk.colour))

      World.line_coverage(world, x, y) > 0.5 ->
        {17, 17, 17}

      true ->
        rgb(World.colour_hex(7))
    end
  end

  @doc """
  A PNG of the arena through a pinhole camera: a webcam on a pole beside the path (the
  roadblock's monitoring node) or a camera on a robot. Walls (15 cm high), robots
  (cylinders 12 cm high), pucks (2 cm; tall objects 10 cm) and the light (a ball 15 cm up,
  yellow when on) stand on the floor, which shows its lines and markers; sides are shaded
  darker than tops. Options:

    * `:pose` - `{x, y, heading}` of the camera, or `:robot` - a robot id: the camera sits
      on its front, 10 cm up, looking where it heads;
    * `:height` - metres above the floor (default 0.35; 0.1 on a robot);
    * `:pitch` - how far it looks down, radians (default 0.6; 0.25 on a robot);
    * `:fov` - horizontal field of view, radians (default 1.1, about 63 degrees);
    * `:pixels` - `{width, height}` (default `{160, 120}`).

      iex> w = TartarusArena.World.new() |> TartarusArena.World.add_robot(:r1, x: 1.5, y: 1.5)
      iex> png = TartarusArena.Render.camera_png(w, robot: :r1, pixels: {32, 24})
      iex> TartarusArena.PNG.size(png)
      {32, 24}
  """
  @spec camera_png(World.t(), keyword()) :: binary()
  def camera_png(world, opts) do
    {{cx, cy, psi}, h, pitch, own} =
      case Keyword.fetch(opts, :robot) do
        {:ok, id} ->
          r = Map.fetch!(world.robots, id)
          d = r.radius + 0.005

          {{r.x + d * :math.cos(r.theta), r.y + d * :math.sin(r.theta), r.theta},
           Keyword.get(opts, :height, 0.1), Keyword.get(opts, :pitch, 0.25), id}

        :error ->
          {Keyword.fetch!(opts, :pose), Keyword.get(opts, :height, 0.35),
           Keyword.get(opts, :pitch, 0.6), nil}
      end

    fov = Keyword.get(opts, :fov, 1.1)
    {pw, ph} = Keyword.get(opts, :pixels, {160, 120})
    f = {:math.cos(psi) * :math.cos(pitch), :math.sin(psi) * :math.cos(pitch), -:math.sin(pitch)}
    rt = {:math.sin(psi), -:math.cos(psi), 0.0}
    up = cross(rt, f)
    k = :math.tan(fov / 2)

    solids =
      for({id, r} <- world.robots, id != own, do: {r.x, r.y, r.radius, 0.12, {157, 183, 213}}) ++
        for {_, p} <- world.pucks,
            do:
              {p.x, p.y, p.radius, if(p.tall, do: 0.1, else: 0.02),
               rgb(World.colour_hex(p.colour))}

    rows =
      for j <- 0..(ph - 1) do
        sy = (1 - 2 * (j + 0.5) / ph) * k * ph / pw

        for i <- 0..(pw - 1), into: <<>> do
          sx = (2 * (i + 0.5) / pw - 1) * k
          d = add(f, add(scale3(rt, sx), scale3(up, sy)))
          {r, g, b} = trace(world, {cx, cy, h}, d, solids)
          <<r, g, b>>
        end
      end

    TartarusArena.PNG.encode(pw, ph, rows)
  end

  @wall_height 0.15

  # The colour the ray from o along d sees first.
  defp trace(world, {ox, oy, oz}, {dx, dy, dz}, solids) do
    dxy = :math.sqrt(dx * dx + dy * dy)
    l = world.light

    floor =
      if dz < 0 do
        t = -oz / dz
        [{t, floor_colour(world, ox + t * dx, oy + t * dy)}]
      else
        []
      end

    walls =
      for seg <- world.walls,
          t = TartarusArena.Geometry.ray_segment(ox, oy, dx, dy, seg),
          z = oz + t * dz,
          z >= 0 and z <= @wall_height,
          do: {t, {90, 90, 96}}

    bodies =
      Enum.flat_map(solids, fn {sx, sy, rad, height, colour} ->
        side =
          if dxy > 1.0e-9 do
            case TartarusArena.Geometry.ray_circle(ox, oy, dx / dxy, dy / dxy, sx, sy, rad) do
              nil ->
                []

              txy ->
                t = txy / dxy
                z = oz + t * dz
                if z >= 0 and z <= height and t > 0, do: [{t, shade(colour, 0.75)}], else: []
            end
          else
            []
          end

        top =
          if dz < 0 and oz > height do
            t = (height - oz) / dz
            if dd(ox + t * dx, oy + t * dy, sx, sy) <= rad, do: [{t, colour}], else: []
          else
            []
          end

        side ++ top
      end)

    light =
      case sphere(ox - l.x, oy - l.y, oz - 0.15, dx, dy, dz, 0.05) do
        nil -> []
        t -> [{t, if(l.on, do: {255, 243, 92}, else: {150, 150, 150})}]
      end

    case Enum.min_by(floor ++ walls ++ bodies ++ light, &elem(&1, 0), fn -> nil end) do
      nil -> {200, 210, 220}
      {_, colour} -> colour
    end
  end

  defp floor_colour(world, x, y) do
    {aw, ah} = world.size

    cond do
      x < 0 or y < 0 or x > aw or y > ah -> {120, 120, 120}
      mk = World.marker_at(world, x, y) -> rgb(World.colour_hex(mk.colour))
      World.line_coverage(world, x, y) > 0.5 -> {17, 17, 17}
      true -> rgb(World.colour_hex(7))
    end
  end

  defp sphere(fx, fy, fz, dx, dy, dz, r) do
    a = dx * dx + dy * dy + dz * dz
    b = 2 * (fx * dx + fy * dy + fz * dz)
    c = fx * fx + fy * fy + fz * fz - r * r
    disc = b * b - 4 * a * c

    if disc < 0 do
      nil
    else
      t = (-b - :math.sqrt(disc)) / (2 * a)
      if t > 0, do: t, else: nil
    end
  end

  defp shade({r, g, b}, k), do: {round(r * k), round(g * k), round(b * k)}

  defp cross({a1, a2, a3}, {b1, b2, b3}),
    do: {a2 * b3 - a3 * b2, a3 * b1 - a1 * b3, a1 * b2 - a2 * b1}

  defp add({a1, a2, a3}, {b1, b2, b3}), do: {a1 + b1, a2 + b2, a3 + b3}
  defp scale3({a1, a2, a3}, k), do: {a1 * k, a2 * k, a3 * k}

  defp dd(x1, y1, x2, y2), do: :math.sqrt((x1 - x2) * (x1 - x2) + (y1 - y2) * (y1 - y2))

  defp rgb("#" <> <<r::binary-size(2), g::binary-size(2), b::binary-size(2)>>),
    do: {String.to_integer(r, 16), String.to_integer(g, 16), String.to_integer(b, 16)}
end
