defmodule TartarusArena.Render do
  @moduledoc """
  Pictures of an arena: an SVG snapshot (`svg/2`), an SVG trajectory plot (`trajectories/3`),
  a PNG as a camera looking straight down on part of the arena would take it (`png/2`), and
  a PNG through a pinhole camera on a pole or on a robot (`camera_png/2`).
  The floor is drawn in its colours (`TartarusArena.World.colour_hex/1`), lines black,
  pucks in their colours, the light as a yellow disc (grey when off), robots as discs with
  a heading mark and their id.
  """

  alias TartarusArena.World

  @palette ~w(#4e79a7 #f28e2b #e15759 #76b7b2 #59a14f #edc948 #b07aa1 #ff9da7 #9c755f #bab0ac)

  @doc """
  An SVG snapshot of the world. Options: `:scale` (pixels per metre, default 200),
  `:title` (default "arena at t = ... s").

      iex> w = TartarusArena.World.new() |> TartarusArena.World.add_robot(:r1, x: 1, y: 1)
      iex> svg = TartarusArena.Render.svg(w)
      iex> String.starts_with?(svg, "<?xml") and svg =~ "r1"
      true
  """
  @spec svg(World.t(), keyword()) :: binary()
  def svg(world, opts \\ []) do
    title = Keyword.get(opts, :title, "arena at t = #{Float.round(world.time, 2)} s")
    doc(world, opts, title, [background(world, opts), robots(world, opts)])
  end

  @doc """
  An SVG of robots' trajectories over the arena's floor: `trajectories` maps a label to a
  list of `{t, x, y}` (as `TartarusArena.Run.laps/3` returns). Options as `svg/2`.
  """
  @spec trajectories(World.t(), %{term() => [{number(), number(), number()}]}, keyword()) ::
          binary()
  def trajectories(world, trajs, opts \\ []) do
    k = scale(opts)
    {_, h} = world.size

    lines =
      trajs
      |> Enum.sort_by(&inspect(elem(&1, 0)))
      |> Enum.with_index()
      |> Enum.map(fn {{label, pts}, i} ->
        colour = Enum.at(@palette, rem(i, length(@palette)))
        coords = Enum.map_join(pts, " ", fn {_t, x, y} -> "#{f(x * k)},#{f((h - y) * k)}" end)

        [
          ~s(<polyline fill="none" stroke="#{colour}" stroke-width="1.5" stroke-opacity="0.8" points="#{coords}"/>),
          ~s(<text x="#{8}" y="#{18 + 16 * i}" fill="#{colour}" font-size="13" font-family="sans-serif">#{esc(label)}</text>)
        ]
      end)

    doc(world, opts, Keyword.get(opts, :title, "trajectories"), [background(world, opts), lines])
  end

  defp doc(world, opts, title, body) do
    k = scale(opts)
    {w, h} = world.size

    IO.iodata_to_binary([
      ~s(<?xml version="1.0" encoding="UTF-8"?>\n),
      ~s(<svg xmlns="http://www.w3.org/2000/svg" width="#{f(w * k)}" height="#{f(h * k)}" viewBox="0 0 #{f(w * k)} #{f(h * k)}">),
      "<title>",
      esc(title),
      "</title>",
      body,
      "</svg>\n"
    ])
  end

  defp background(world, opts) do
    k = scale(opts)
    {w, h} = world.size
    y = fn v -> f((h - v) * k) end

    [
      ~s(<rect x="0" y="0" width="#{f(w * k)}" height="#{f(h * k)}" fill="#{World.colour_hex(7)}"/>),
      for m <- world.markers do
        [
          ~s(<rect x="#{f((m.x - m.w / 2) * k)}" y="#{y.(m.y + m.h / 2)}" width="#{f(m.w * k)}" height="#{f(m.h * k)}" fill="#{World.colour_hex(m.colour)}"/>),
          if(m.label,
            do:
              ~s(<text x="#{f((m.x + m.w / 2) * k + 3)}" y="#{y.(m.y)}" font-size="11" font-family="sans-serif">#{esc(m.label)}</text>),
            else: []
          )
        ]
      end,
      for l <- world.lines do
        pts = Enum.map_join(l.points, " ", fn {px, py} -> "#{f(px * k)},#{y.(py)}" end)

        ~s(<polyline fill="none" stroke="#111" stroke-linejoin="miter" stroke-width="#{f(l.width * k)}" points="#{pts}"/>)
      end,
      for {wx1, wy1, wx2, wy2} <- world.walls do
        ~s(<line x1="#{f(wx1 * k)}" y1="#{y.(wy1)}" x2="#{f(wx2 * k)}" y2="#{y.(wy2)}" stroke="#444" stroke-width="4"/>)
      end,
      ~s(<circle cx="#{f(world.light.x * k)}" cy="#{y.(world.light.y)}" r="#{f(0.05 * k)}" fill="#{if world.light.on, do: "#fff35c", else: "#999"}" stroke="#555"/>),
      for {_, p} <- Enum.sort_by(world.pucks, &inspect(elem(&1, 0))) do
        ~s(<circle cx="#{f(p.x * k)}" cy="#{y.(p.y)}" r="#{f(p.radius * k)}" fill="#{World.colour_hex(p.colour)}" stroke="#333"/>)
      end
    ]
  end

  defp robots(world, opts) do
    k = scale(opts)
    {_, h} = world.size

    for {id, r} <- Enum.sort_by(world.robots, &inspect(elem(&1, 0))) do
      cx = r.x * k
      cy = (h - r.y) * k
      hx = (r.x + r.radius * :math.cos(r.theta)) * k
      hy = (h - r.y - r.radius * :math.sin(r.theta)) * k

      [
        ~s(<circle cx="#{f(cx)}" cy="#{f(cy)}" r="#{f(r.radius * k)}" fill="#9db7d5" fill-opacity="0.85" stroke="#234"/>),
        ~s(<line x1="#{f(cx)}" y1="#{f(cy)}" x2="#{f(hx)}" y2="#{f(hy)}" stroke="#234" stroke-width="2"/>),
        ~s(<text x="#{f(cx + r.radius * k + 2)}" y="#{f(cy - r.radius * k)}" font-size="12" font-family="sans-serif">#{esc(id)}</text>)
      ]
    end
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

  defp scale(opts), do: Keyword.get(opts, :scale, 200)
  defp f(v), do: :erlang.float_to_binary(v * 1.0, decimals: 1)

  defp esc(term) do
    s =
      if is_binary(term),
        do: term,
        else: if(is_atom(term) or is_number(term), do: to_string(term), else: inspect(term))

    s
    |> String.replace("&", "&amp;")
    |> String.replace("<", "&lt;")
    |> String.replace(">", "&gt;")
  end
end
