defmodule TartarusArena.Render do
  @moduledoc """
  Pictures of an arena: an SVG snapshot (`svg/2`), an SVG trajectory plot (`trajectories/3`)
  and a PNG as a camera looking down on part of the arena would take it (`png/2`).
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
