defmodule TartarusArena.World do
  @moduledoc """
  The arena as a pure value: walls, differential-drive robots, pucks, a light, floor
  markings, and a seeded random stream. `step/3` integrates it by one fixed step;
  `sense/2` reads a robot's sensors. No process, no clock: the same seed and the same
  commands give the same world, bit for bit.

      iex> w = TartarusArena.World.new(seed: 1, noise: :none)
      iex> w = TartarusArena.World.add_robot(w, :r1, x: 1.0, y: 1.0, theta: 0.0)
      iex> w = Enum.reduce(1..50, w, fn _, w -> TartarusArena.World.step(w, %{r1: {1.0, 1.0}}, 0.02) end)
      iex> {x, y, _} = TartarusArena.World.pose(w, :r1)
      iex> {Float.round(x, 3), Float.round(y, 3)}
      {1.25, 1.0}

  ## Units and frame

  Metres, seconds, radians. The origin is the arena's lower-left corner, x to the right,
  y up; a heading `theta` of 0 points along +x and grows counter-clockwise. Time is the
  world's own simulated time (`time/1`), advanced only by `step/3`.

  ## Robots

  A robot is a disc of radius `radius` (default 0.07 m) on two wheels `axle` apart
  (default 0.11 m) with a castor, like the thesis's LEGO NXT robots. A wheel command is a
  fraction of the top speed in `[-1, 1]` (values outside are clipped: the speed limit);
  `max_speed` is the top wheel speed (default 0.25 m/s, about an NXT motor at 70% on
  5.6 cm wheels). Each step each wheel's actual speed is the command times `max_speed`
  times `1 + N(0, noise.wheel)` (default 0.03), drawn from the world's stream.

  With `accel` (m/s², default none) a wheel's actual speed follows that target at most
  `accel * dt` per step (inertia: a robot cannot stop, start or reverse a wheel at once);
  it starts at rest and `place/3` leaves it at rest. Without it the speed is the target at
  once (the default: a kinematic robot).

  The pose is integrated with the midpoint rule: `v = (vl + vr) / 2`,
  `omega = (vr - vl) / axle`, `x += v dt cos(theta + omega dt / 2)` (same for y),
  `theta += omega dt`. A step longer than half a radius of travel is cut into sub-steps.

  A robot's `tool` is `:none`, `:pusher` (a passive U-shaped gripper: a puck in front of
  the robot stays there while the robot drives forward or turns, and is left behind when it
  backs off) or `:claws` (`grip/3` with `:close` holds the puck in front, even backwards,
  until `:open`). These describe capabilities for the roadblock scenario (Rudolph pushes,
  Claus grips) and the pushing tasks of the evolution scenarios.

  ## Collisions

  Walls are segments; the four borders are always there. A robot that drives into a free
  puck pushes it along the line between their centres. Pucks are light, as on a floor: a
  puck pushed into a wall at an angle slides along the wall, keeping in contact with what
  pushes it (at most twice as far as the push: a push close to head-on jams it), and a
  puck pushed into a free puck pushes that one along the line between their centres, down
  a chain of up to 3 pucks. A puck held in claws does not slide. A move is refused (the
  robot keeps its pose, `bumped` is set) if the robot's path crosses a wall, ends closer
  to a wall than its radius, overlaps another robot, or would push a puck, so resolved,
  into a wall, a robot, a held puck, a corner or a longer chain. A refused move is tried
  again as a turn in place, then dropped; a pusher's cupped pucks that cannot follow such
  a turn slip out of its shallow U and stay where they are (the disc-shaped robot itself
  can always turn in place). So no robot ever passes through a wall, whatever the
  commands. Robots move one at a time, in the order of their ids, each against the
  others' current poses.

  ## Sensors (`sense/2`)

    * `ultrasonic` - 0..200 (cm; high = far), the nearest echo over a cone of 5 rays
      spanning 30 degrees from the robot's front: walls, other robots and tall objects
      (blocks; pucks are too low), capped at 200, noise N(0, 1 cm);
    * `colour` - 0..9 under the front of the robot: a puck in the gripper gives the
      puck's colour (yellow = 3), else a floor marker's colour, else 0 on a black line,
      else 7 (the plain floor, the thesis's default); with probability `noise.colour`
      (default 0.01) a misread, uniform over 0..9. Colours: 0 black, 1 blue, 2 green,
      3 yellow, 4 red, 5 white, 6 orange, 7 floor, 8 purple, 9 brown;
    * `light` - `{left, right}`, 0..100 (high = near the light): two sensors on the sides
      looking 45 degrees left and right of the heading; the light is a bulb 0.12 m above
      them (15 cm above the floor, over the robots' heads: the camera draws it there).
      With `r` the distance from the robot's centre to the point under the bulb,
      `d = sqrt(r^2 + 0.12^2)` the distance to the bulb, `c = r / d` (the cosine of its
      elevation) and `phi` the angle between the sensor's axis and the bulb's bearing,
      the reading is `5 + 95 f / (1 + (d / 0.5)^2)` with
      `f = 0.3 + 0.7 (1 - c (1 - (1 + cos phi) / 2))`: more for the sensor facing the
      bulb (0.3 facing away to 1 facing it, far off), the same for both right under it
      (`f = 1`), and growing along any straight approach to the light (about 95 under
      the bulb, 47 facing it from 0.5 m, 16-18 facing it from a corner of a 2 m
      arena); 5 (ambient) when the light is off; noise N(0, 1);
    * `line` - `{left, right}`, 0..100 reflected light of two downward sensors 6 cm ahead
      of the axle and 2.5 cm either side of the centre line: 60 on the floor, 12 on black
      tape (2 cm wide), blended over the sensor's 8 mm spot, noise N(0, 1). They straddle
      a line: both read white when the robot is centred. With the world's
      `line_footprint` (a radius, m; default none) each sensor sees a disc of that radius
      instead, and reads the black fraction of 32 points spread evenly over the disc
      (a sunflower pattern), so a black corner or tip inside the disc counts as it covers
      it;
    * `bumped` - whether the robot's last move was refused; `holding` - the id of the puck
      in its claws or nil; `puck_in_gripper` - whether a puck is in the gripper zone.

  Readings are integers, like the NXT's. `noise: :none` makes every sensor and wheel exact.
  """

  alias TartarusArena.Geometry, as: G

  @typedoc "A robot's or puck's id (any term; robots move in the order of their ids)."
  @type id :: term()

  @typedoc "A pose: x, y (m) and heading (rad)."
  @type pose :: {float(), float(), float()}

  @typedoc "A wheel command: left and right speed as fractions of `max_speed`, in [-1, 1]."
  @type wheels :: {number(), number()}

  @typedoc "One robot's command for a step: wheels, or a keyword list with `:wheels` and `:grip`."
  @type command :: wheels() | [wheels: wheels(), grip: :open | :close]

  @typedoc "A robot's sensor readings (see the moduledoc)."
  @type readings :: %{
          ultrasonic: 0..200,
          colour: 0..9,
          light: {0..100, 0..100},
          line: {0..100, 0..100},
          bumped: boolean(),
          holding: id() | nil,
          puck_in_gripper: boolean()
        }

  @typedoc "The world."
  @type t :: %__MODULE__{}

  defstruct size: {3.0, 3.0},
            walls: [],
            robots: %{},
            order: [],
            pucks: %{},
            light: %{x: 1.5, y: 1.5, on: false},
            lines: [],
            line_index: %{},
            markers: [],
            rng: nil,
            time: 0.0,
            noise: %{},
            line_footprint: nil

  @default_noise %{wheel: 0.03, ultrasonic: 1.0, light: 1.0, line: 1.0, colour: 0.01}

  @point {:tuple, [:number, :number]}
  @pos_number {:custom, &TartarusArena.World.positive?/1}

  @new_schema [
    size: [
      type: {:tuple, [@pos_number, @pos_number]},
      default: {3.0, 3.0},
      expected: "{width, height} in metres, both positive",
      doc: "the arena's `{width, height}` in metres"
    ],
    seed: [type: :any, default: 0, doc: "seed of the world's random stream (any term)"],
    noise: [
      type: {:or, [{:in, [:none]}, :map]},
      default: %{},
      doc: "`:none`, or a map overriding the noise levels"
    ],
    walls: [
      type: {:list, {:tuple, [@point, @point]}},
      default: [],
      doc: "extra wall segments `{{x1, y1}, {x2, y2}}`"
    ],
    light: [type: :keyword, default: [], doc: "`[x:, y:, on:]` (default the centre, off)"],
    line_footprint: [
      type: {:or, [{:in, [nil]}, @pos_number]},
      default: nil,
      expected: "nil or a positive number",
      doc: "radius (m) of the line sensors' disc footprint; nil: the 8 mm spot"
    ]
  ]

  @robot_schema [
    x: [type: :number, required: true, doc: "x (m)"],
    y: [type: :number, required: true, doc: "y (m)"],
    theta: [type: :number, default: 0.0, doc: "heading (rad)"],
    radius: [type: @pos_number, default: 0.07, expected: "a positive number", doc: "m"],
    axle: [
      type: @pos_number,
      default: 0.11,
      expected: "a positive number",
      doc: "wheel distance (m)"
    ],
    max_speed: [
      type: @pos_number,
      default: 0.25,
      expected: "a positive number",
      doc: "top wheel speed (m/s)"
    ],
    tool: [
      type: {:in, [:none, :pusher, :claws]},
      default: :none,
      doc: "`:none`, `:pusher` or `:claws`"
    ],
    accel: [
      type: {:or, [{:in, [nil]}, @pos_number]},
      default: nil,
      expected: "nil or a positive number",
      doc: "a wheel's acceleration limit (m/s²); nil: none (kinematic)"
    ]
  ]

  @puck_schema [
    x: [type: :number, required: true, doc: "x (m)"],
    y: [type: :number, required: true, doc: "y (m)"],
    radius: [type: @pos_number, default: 0.03, expected: "a positive number", doc: "m"],
    colour: [type: {:in, Enum.to_list(0..9)}, default: 3, doc: "0..9 (3: yellow)"],
    tall: [type: :boolean, default: false, doc: "seen by the ultrasonic sensor"]
  ]
  @no_noise %{wheel: 0.0, ultrasonic: 0.0, light: 0.0, line: 0.0, colour: 0.0}

  @sensors [:ultrasonic, :colour, :light, :line, :bumped, :holding, :puck_in_gripper]
  @us_rays [-0.2618, -0.1309, 0.0, 0.1309, 0.2618]
  @us_range 2.0
  @line_ahead 0.06
  @line_lateral 0.025
  @spot 0.008
  @floor_reflect 60.0
  @black_reflect 12.0
  @cell 0.1
  @zone_angle 0.6
  @zone_slack 0.015
  @bulb_height 0.12
  @light_axis :math.pi() / 4
  @light_falloff 0.5

  @reflect %{
    0 => 12.0,
    1 => 25.0,
    2 => 30.0,
    3 => 55.0,
    4 => 45.0,
    5 => 70.0,
    6 => 50.0,
    7 => 60.0,
    8 => 28.0,
    9 => 22.0
  }

  @colours %{
    0 => "#111111",
    1 => "#2f6fd0",
    2 => "#3aa845",
    3 => "#f2c418",
    4 => "#d8332a",
    5 => "#ffffff",
    6 => "#f08a24",
    7 => "#e6e2d8",
    8 => "#8a4fb0",
    9 => "#8b5a2b"
  }

  @doc false
  def positive?(v), do: is_number(v) and v > 0

  @doc """
  A new, empty arena.

  Options (the noise levels are `#{inspect(@default_noise)}`; bad options raise
  `ArgumentError` naming the key, what was expected and what arrived):

  #{Tartarus.Options.docs(@new_schema)}

      iex> w = TartarusArena.World.new(size: {2.0, 2.0})
      iex> length(w.walls)
      4
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    opts = Tartarus.Options.validate!(opts, @new_schema, "TartarusArena.World.new/1")
    {w, h} = size = Keyword.get(opts, :size, {3.0, 3.0})
    {w, h} = {w * 1.0, h * 1.0}

    noise =
      case Keyword.get(opts, :noise, %{}) do
        :none -> @no_noise
        m when is_map(m) -> Map.merge(@default_noise, m)
      end

    border = [{0.0, 0.0, w, 0.0}, {w, 0.0, w, h}, {w, h, 0.0, h}, {0.0, h, 0.0, 0.0}]

    extra =
      for {{x1, y1}, {x2, y2}} <- Keyword.get(opts, :walls, []),
          do: {x1 * 1.0, y1 * 1.0, x2 * 1.0, y2 * 1.0}

    light = Keyword.get(opts, :light, [])

    %__MODULE__{
      size: {elem(size, 0) * 1.0, elem(size, 1) * 1.0},
      walls: border ++ extra,
      rng: :rand.seed_s(Tartarus.Random.new({:arena, Keyword.get(opts, :seed, 0)})),
      noise: noise,
      line_footprint: Keyword.get(opts, :line_footprint),
      light: %{
        x: Keyword.get(light, :x, w / 2) * 1.0,
        y: Keyword.get(light, :y, h / 2) * 1.0,
        on: Keyword.get(light, :on, false)
      }
    }
  end

  @doc """
  Adds a robot. Raises `ArgumentError` for a bad option or if the robot would overlap a
  wall or another robot. Options:

  #{Tartarus.Options.docs(@robot_schema)}
  """
  @spec add_robot(t(), id(), keyword()) :: t()
  def add_robot(%__MODULE__{} = w, id, opts) do
    opts = Tartarus.Options.validate!(opts, @robot_schema, "TartarusArena.World.add_robot/3")

    r = %{
      id: id,
      x: Keyword.fetch!(opts, :x) * 1.0,
      y: Keyword.fetch!(opts, :y) * 1.0,
      theta: Keyword.get(opts, :theta, 0.0) * 1.0,
      radius: Keyword.get(opts, :radius, 0.07) * 1.0,
      axle: Keyword.get(opts, :axle, 0.11) * 1.0,
      max_speed: Keyword.get(opts, :max_speed, 0.25) * 1.0,
      tool: Keyword.get(opts, :tool, :none),
      cmd: {0.0, 0.0},
      held: nil,
      bumped: false,
      odometer: 0.0,
      accel: Keyword.get(opts, :accel),
      vel: {0.0, 0.0}
    }

    if Enum.any?(w.walls, &(G.dist_segment(r.x, r.y, &1) < r.radius)) or
         Enum.any?(w.robots, fn {_, o} -> G.dist(r.x, r.y, o.x, o.y) < r.radius + o.radius end) do
      raise ArgumentError,
            "robot #{inspect(id)} at #{inspect({r.x, r.y})} overlaps a wall or another robot"
    end

    %{w | robots: Map.put(w.robots, id, r), order: Enum.sort([id | List.delete(w.order, id)])}
  end

  @doc """
  Adds a puck (or any movable object; a roadblock is a tall green one). Options:

  #{Tartarus.Options.docs(@puck_schema)}
  """
  @spec add_puck(t(), id(), keyword()) :: t()
  def add_puck(%__MODULE__{} = w, id, opts) do
    opts = Tartarus.Options.validate!(opts, @puck_schema, "TartarusArena.World.add_puck/3")

    p = %{
      id: id,
      x: Keyword.fetch!(opts, :x) * 1.0,
      y: Keyword.fetch!(opts, :y) * 1.0,
      radius: Keyword.get(opts, :radius, 0.03) * 1.0,
      colour: Keyword.get(opts, :colour, 3),
      tall: Keyword.get(opts, :tall, false),
      held_by: nil
    }

    %{w | pucks: Map.put(w.pucks, id, p)}
  end

  @doc "Removes a puck (e.g. a roadblock carried off the arena)."
  @spec remove_puck(t(), id()) :: t()
  def remove_puck(%__MODULE__{} = w, id) do
    robots =
      Map.new(w.robots, fn {rid, r} -> {rid, if(r.held == id, do: %{r | held: nil}, else: r)} end)

    %{w | pucks: Map.delete(w.pucks, id), robots: robots}
  end

  @doc """
  Adds a black line (a polyline of `{x, y}` points) painted on the floor. Options:
  `:width` (default 0.02 m), `:closed` (default false: join the last point to the first).
  """
  @spec add_line(t(), [{number(), number()}], keyword()) :: t()
  def add_line(%__MODULE__{} = w, points, opts \\ []) do
    width = Keyword.get(opts, :width, 0.02) * 1.0
    pts = Enum.map(points, fn {x, y} -> {x * 1.0, y * 1.0} end)
    pts = if Keyword.get(opts, :closed, false), do: pts ++ [hd(pts)], else: pts

    segs =
      pts
      |> Enum.chunk_every(2, 1, :discard)
      |> Enum.map(fn [{ax, ay}, {bx, by}] -> {ax, ay, bx, by, width} end)

    %{w | lines: [%{points: pts, width: width} | w.lines], line_index: index(w.line_index, segs)}
  end

  defp index(idx, segs) do
    margin = 0.05

    Enum.reduce(segs, idx, fn {ax, ay, bx, by, _} = seg, idx ->
      for i <- cell(min(ax, bx) - margin)..cell(max(ax, bx) + margin),
          j <- cell(min(ay, by) - margin)..cell(max(ay, by) + margin),
          reduce: idx do
        idx -> Map.update(idx, {i, j}, [seg], &[seg | &1])
      end
    end)
  end

  defp cell(v), do: floor(v / @cell)

  @doc """
  Adds a coloured floor marker, a rectangle. Options: `:x`, `:y` (centre), `:w`, `:h`
  (metres, default 0.1), `:colour` (0..9), `:label` (shown in renderings).
  """
  @spec add_marker(t(), keyword()) :: t()
  def add_marker(%__MODULE__{} = w, opts) do
    m = %{
      x: Keyword.fetch!(opts, :x) * 1.0,
      y: Keyword.fetch!(opts, :y) * 1.0,
      w: Keyword.get(opts, :w, 0.1) * 1.0,
      h: Keyword.get(opts, :h, 0.1) * 1.0,
      colour: Keyword.fetch!(opts, :colour),
      label: Keyword.get(opts, :label)
    }

    %{w | markers: w.markers ++ [m]}
  end

  @doc "Switches the light `:on` or `:off`."
  @spec set_light(t(), :on | :off) :: t()
  def set_light(%__MODULE__{} = w, state) when state in [:on, :off],
    do: %{w | light: %{w.light | on: state == :on}}

  @doc "Whether the light is on."
  @spec light_on?(t()) :: boolean()
  def light_on?(%__MODULE__{light: l}), do: l.on

  @doc "Sets a robot's wheel command; it holds until changed."
  @spec set_wheels(t(), id(), number(), number()) :: t()
  def set_wheels(%__MODULE__{} = w, id, l, r) when is_number(l) and is_number(r),
    do: update_robot(w, id, &%{&1 | cmd: {clip(l), clip(r)}})

  @doc """
  Closes (`:close`) or opens (`:open`) a robot's claws. Closing takes the puck in the
  gripper zone, if any and if the robot has claws; opening drops what it holds.
  """
  @spec grip(t(), id(), :open | :close) :: t()
  def grip(%__MODULE__{} = w, id, :open) do
    r = Map.fetch!(w.robots, id)

    case r.held do
      nil ->
        w

      p ->
        %{w | robots: Map.put(w.robots, id, %{r | held: nil}), pucks: put_held(w.pucks, p, nil)}
    end
  end

  def grip(%__MODULE__{} = w, id, :close) do
    r = Map.fetch!(w.robots, id)

    with :claws <- r.tool,
         nil <- r.held,
         [p | _] <- in_zone(w, r) do
      %{w | robots: Map.put(w.robots, id, %{r | held: p.id}), pucks: put_held(w.pucks, p.id, id)}
    else
      _ -> w
    end
  end

  defp put_held(pucks, pid, by), do: Map.update!(pucks, pid, &%{&1 | held_by: by})

  @doc "A robot's pose `{x, y, theta}` (ground truth, for tracking and plots)."
  @spec pose(t(), id()) :: pose()
  def pose(%__MODULE__{} = w, id) do
    r = Map.fetch!(w.robots, id)
    {r.x, r.y, r.theta}
  end

  @doc "Moves a robot to a pose (no collision check: for setting up trials)."
  @spec place(t(), id(), pose()) :: t()
  def place(%__MODULE__{} = w, id, {x, y, th}),
    do:
      update_robot(
        w,
        id,
        &%{&1 | x: x * 1.0, y: y * 1.0, theta: th * 1.0, bumped: false, vel: {0.0, 0.0}}
      )

  @doc """
  A robot's commanded motion: forward speed `v` (m/s) and turn rate `omega` (rad/s) of its
  current wheel command (no noise), and both normalized to 0..1 (`v_trans` = |v| /
  max_speed, `v_rot` = |omega| / (2 max_speed / axle)): the terms of the thesis's
  obstacle-avoidance fitness `f_obs = v_trans (1 - v_rot) d` (Eq. 7.1).

      iex> w = TartarusArena.World.new() |> TartarusArena.World.add_robot(:r, x: 1, y: 1)
      iex> TartarusArena.World.motion(TartarusArena.World.set_wheels(w, :r, 1.0, 0.0), :r).v_rot
      0.5
  """
  @spec motion(t(), id()) :: %{v: float(), omega: float(), v_trans: float(), v_rot: float()}
  def motion(%__MODULE__{} = w, id) do
    r = Map.fetch!(w.robots, id)
    {cl, cr} = r.cmd
    v = (cl + cr) / 2 * r.max_speed
    om = (cr - cl) * r.max_speed / r.axle

    %{
      v: v,
      omega: om,
      v_trans: abs(v) / r.max_speed,
      v_rot: abs(om) / (2 * r.max_speed / r.axle)
    }
  end

  @doc """
  The inputs of the thesis's 4-5-2 neural controller (§7.3): the two light sensors, the
  ultrasonic and the colour sensor, each normalized to 0..1, in that order.

      iex> TartarusArena.World.normalize(%{light: {100, 50}, ultrasonic: 200, colour: 3})
      [1.0, 0.5, 1.0, 0.3333333333333333]
  """
  @spec normalize(map()) :: [float()]
  def normalize(%{light: {l, r}, ultrasonic: us, colour: c}),
    do: [l / 100, r / 100, us / 200, c / 9]

  @doc "The world's simulated time in seconds."
  @spec time(t()) :: float()
  def time(%__MODULE__{time: t}), do: t

  @doc "The display colour (hex) of a colour code 0..9."
  @spec colour_hex(0..9) :: String.t()
  def colour_hex(c), do: Map.get(@colours, c, "#999999")

  defp update_robot(w, id, fun), do: %{w | robots: Map.update!(w.robots, id, fun)}

  defp clip(v), do: max(-1.0, min(1.0, v * 1.0))

  ## Stepping

  @doc """
  Advances the world by `dt` seconds. `commands` maps robot ids to a wheel command
  `{left, right}` or a keyword list `[wheels: {l, r}, grip: :open | :close]`; robots not
  named keep their last command.
  """
  @spec step(t(), %{optional(id()) => command()}, number()) :: t()
  def step(%__MODULE__{} = w, commands, dt) when is_number(dt) and dt > 0 do
    w =
      Enum.reduce(commands, w, fn
        {id, {l, r}}, w ->
          set_wheels(w, id, l, r)

        {id, kw}, w when is_list(kw) ->
          w = if wh = kw[:wheels], do: set_wheels(w, id, elem(wh, 0), elem(wh, 1)), else: w
          if g = kw[:grip], do: grip(w, id, g), else: w
      end)

    w = Enum.reduce(w.order, w, fn id, w -> move(w, Map.fetch!(w.robots, id), dt * 1.0) end)
    %{w | time: w.time + dt}
  end

  defp move(w, r, dt) do
    {cl, cr} = r.cmd
    {nl, rng} = :rand.normal_s(w.rng)
    {nr, rng} = :rand.normal_s(rng)
    w = %{w | rng: rng}

    {vl, vr} =
      wheel_speeds(
        r,
        cl * r.max_speed * (1 + w.noise.wheel * nl),
        cr * r.max_speed * (1 + w.noise.wheel * nr),
        dt
      )

    w = if r.accel, do: update_robot(w, r.id, &%{&1 | vel: {vl, vr}}), else: w
    v = (vl + vr) / 2
    om = (vr - vl) / r.axle
    n = max(1, ceil(abs(v * dt) / (r.radius / 2)))
    h = dt / n

    {w, bumped} =
      Enum.reduce(1..n, {w, false}, fn _, {w, bumped} ->
        r = Map.fetch!(w.robots, r.id)
        thm = r.theta + om * h / 2
        nx = r.x + v * h * :math.cos(thm)
        ny = r.y + v * h * :math.sin(thm)
        nth = G.wrap_angle(r.theta + om * h)

        case attempt(w, r, nx, ny, nth, v, true) do
          {:ok, w} ->
            {w, bumped}

          :blocked ->
            # a refused move is tried as a turn in place; a pusher's cupped pucks that
            # cannot follow the turn slip out of its shallow U (the disc-shaped robot
            # itself can always turn in place)
            with :blocked <- attempt(w, r, r.x, r.y, nth, v, true),
                 :blocked <- attempt(w, r, r.x, r.y, nth, v, false) do
              {w, true}
            else
              {:ok, w} -> {w, true}
            end
        end
      end)

    update_robot(w, r.id, &%{&1 | bumped: bumped})
  end

  # the wheels' actual speeds: the targets, or (with an acceleration limit) the last
  # speeds moved towards them by at most accel * dt
  defp wheel_speeds(%{accel: nil}, tl, tr, _dt), do: {tl, tr}

  defp wheel_speeds(%{accel: a, vel: {pl, pr}}, tl, tr, dt) do
    dv = a * dt
    {pl + max(-dv, min(dv, tl - pl)), pr + max(-dv, min(dv, tr - pr))}
  end

  # Tries to move robot r to (nx, ny, nth) (with its cupped pucks if `cup`); returns the
  # new world or :blocked.
  defp attempt(w, r, nx, ny, nth, v, cup) do
    carried = carried(w, r, v, cup)

    with false <- robot_hits_wall?(w, r, nx, ny),
         false <- robot_hits_robot?(w, r, nx, ny),
         {:ok, moves} <- move_carried(w, r, carried, nx, ny, nth),
         {:ok, moves} <- push_pucks(w, r, nx, ny, moves, Enum.map(carried, & &1.id)) do
      pucks =
        Enum.reduce(moves, w.pucks, fn {pid, {px, py}}, acc ->
          Map.update!(acc, pid, &%{&1 | x: px, y: py})
        end)

      d = G.dist(r.x, r.y, nx, ny)
      robots = Map.put(w.robots, r.id, %{r | x: nx, y: ny, theta: nth, odometer: r.odometer + d})
      {:ok, %{w | robots: robots, pucks: pucks}}
    else
      _ -> :blocked
    end
  end

  defp robot_hits_wall?(w, r, nx, ny) do
    reach = r.radius + abs(nx - r.x) + abs(ny - r.y) + 1.0e-6

    Enum.any?(w.walls, fn seg ->
      near?(nx, ny, reach, seg) and
        (G.segments_cross?(r.x, r.y, nx, ny, seg) or
           (
             dn = G.dist_segment(nx, ny, seg)
             dn < r.radius and dn < G.dist_segment(r.x, r.y, seg)
           ))
    end)
  end

  # Whether (x, y) is within `reach` of the segment's bounding box (a cheap first look).
  defp near?(x, y, reach, {ax, ay, bx, by}) do
    x + reach >= min(ax, bx) and x - reach <= max(ax, bx) and y + reach >= min(ay, by) and
      y - reach <= max(ay, by)
  end

  defp robot_hits_robot?(w, r, nx, ny) do
    Enum.any?(w.robots, fn {oid, o} ->
      oid != r.id and
        (
          dn = G.dist(nx, ny, o.x, o.y)
          dn < r.radius + o.radius and dn < G.dist(r.x, r.y, o.x, o.y)
        )
    end)
  end

  # Pucks that move with the robot: held in claws, or cupped by a pusher going forward.
  defp carried(w, r, v, cup) do
    cond do
      r.held != nil -> [Map.fetch!(w.pucks, r.held)]
      cup and r.tool == :pusher and v >= 0 -> in_zone(w, r)
      true -> []
    end
  end

  defp in_zone(w, r) do
    w.pucks
    |> Map.values()
    |> Enum.filter(fn p ->
      p.held_by == nil and
        G.dist(r.x, r.y, p.x, p.y) <= r.radius + p.radius + @zone_slack and
        abs(G.wrap_angle(:math.atan2(p.y - r.y, p.x - r.x) - r.theta)) <= @zone_angle
    end)
    |> Enum.sort_by(&G.dist(r.x, r.y, &1.x, &1.y))
  end

  # The carried pucks keep their place in the robot's frame (a held one sits in the
  # claws); returns the puck moves `%{id => {x, y}}` or :blocked.
  defp move_carried(w, r, carried, nx, ny, nth) do
    skip = Enum.map(carried, & &1.id)

    Enum.reduce_while(carried, {:ok, %{}}, fn p, {:ok, moves} ->
      {px, py} =
        if r.held == p.id do
          d = r.radius + p.radius + 0.002
          {nx + d * :math.cos(nth), ny + d * :math.sin(nth)}
        else
          # keep the puck's position in the robot's frame
          dx = p.x - r.x
          dy = p.y - r.y
          dth = nth - r.theta
          c = :math.cos(dth)
          s = :math.sin(dth)
          {nx + c * dx - s * dy, ny + s * dx + c * dy}
        end

      # a held puck is fixed in the claws; a cupped one may slide along a wall
      pusher = if r.held == p.id, do: nil, else: {nx, ny, r.radius}

      case shove(w, {r.id, nx, ny}, p, {px, py}, pusher, moves, skip, 0) do
        {:ok, moves} -> {:cont, {:ok, moves}}
        :blocked -> {:halt, :blocked}
      end
    end)
  end

  # The robot's body, at its new place, pushes the free pucks it would overlap along the
  # line between their centres.
  defp push_pucks(w, r, nx, ny, moves, skip) do
    Enum.reduce_while(w.pucks, {:ok, moves}, fn {pid, p}, {:ok, moves} ->
      dn = G.dist(nx, ny, p.x, p.y)
      reach = r.radius + p.radius

      cond do
        Map.has_key?(moves, pid) or pid in skip or dn >= reach ->
          {:cont, {:ok, moves}}

        p.held_by != nil ->
          {:halt, :blocked}

        true ->
          {ux, uy} =
            if dn < 1.0e-9,
              do: {:math.cos(r.theta), :math.sin(r.theta)},
              else: {(p.x - nx) / dn, (p.y - ny) / dn}

          target = {nx + ux * (reach + 1.0e-4), ny + uy * (reach + 1.0e-4)}

          case shove(w, {r.id, nx, ny}, p, target, {nx, ny, r.radius}, moves, skip, 0) do
            {:ok, moves} -> {:cont, {:ok, moves}}
            :blocked -> {:halt, :blocked}
          end
      end
    end)
  end

  @chain 3

  # Moves puck p towards `target`, driven by `pusher` (the disc `{x, y, radius}` behind it,
  # or nil for a puck held in claws). Light pucks behave as pucks do on a floor:
  #   * one that meets a wall at an angle slides along it, staying in contact with its
  #     pusher (a head-on push into a wall, or into a corner, is refused);
  #   * one that meets a free puck pushes it along the line between their centres, and so
  #     on down a chain of up to @chain pucks.
  # `mover` is the moving robot's id and new place (the other robots stand still); `moves`
  # the pucks already moved in this step; `skip` pucks moved by the robot afterwards
  # (checked when they move). Returns `{:ok, moves}` or :blocked.
  defp shove(w, {rid, rx, ry} = mover, p, target, pusher, moves, skip, depth) do
    with {:ok, {px, py}} <- against_walls(w, p, target, pusher),
         false <-
           Enum.any?(w.robots, fn {oid, o} ->
             {ox, oy} = if oid == rid, do: {rx, ry}, else: {o.x, o.y}
             G.dist(px, py, ox, oy) < p.radius + o.radius - 1.0e-6
           end),
         false <-
           Enum.any?(moves, fn {qid, {qx, qy}} ->
             qid != p.id and G.dist(px, py, qx, qy) < p.radius + w.pucks[qid].radius - 1.0e-6
           end) do
      moves = Map.put(moves, p.id, {px, py})

      w.pucks
      |> Map.values()
      |> Enum.filter(fn q ->
        q.id != p.id and not Map.has_key?(moves, q.id) and q.id not in skip and
          G.dist(px, py, q.x, q.y) < p.radius + q.radius
      end)
      |> Enum.reduce_while({:ok, moves}, fn q, {:ok, moves} ->
        if q.held_by != nil or depth >= @chain do
          {:halt, :blocked}
        else
          dn = G.dist(px, py, q.x, q.y)
          reach = p.radius + q.radius + 1.0e-4

          {ux, uy} =
            if dn < 1.0e-9, do: unit(px - p.x, py - p.y), else: {(q.x - px) / dn, (q.y - py) / dn}

          case shove(
                 w,
                 mover,
                 q,
                 {px + ux * reach, py + uy * reach},
                 {px, py, p.radius},
                 moves,
                 skip,
                 depth + 1
               ) do
            {:ok, moves} -> {:cont, {:ok, moves}}
            :blocked -> {:halt, :blocked}
          end
        end
      end)
    else
      _ -> :blocked
    end
  end

  # Where puck p ends up when driven to `target` by `pusher` with the walls in the way:
  # the target itself if free; else, for a puck with a pusher, the target brought back to
  # touch the wall it meets and then moved along that wall until the pusher no longer
  # overlaps it (the puck slides along the wall); :blocked if that place is not free either
  # (a corner) or the push is (close to) head-on.
  defp against_walls(w, p, {px, py} = target, pusher) do
    case Enum.find(w.walls, &puck_in_wall?(p, px, py, &1)) do
      nil ->
        {:ok, target}

      _ when pusher == nil ->
        :blocked

      seg ->
        {cx, cy} = closest_point(p.x, p.y, seg)
        {nx, ny} = unit(p.x - cx, p.y - cy)
        {tx, ty} = {-ny, nx}
        h = p.radius + 1.0e-4
        # the target moved along the normal to touch the wall
        dn = (px - cx) * nx + (py - cy) * ny
        {qx, qy} = {px + (h - dn) * nx, py + (h - dn) * ny}
        along = (px - p.x) * tx + (py - p.y) * ty

        # a push too close to head-on jams the puck rather than sliding it (the slide may
        # be at most twice the push: friction)
        with {:ok, {sx, sy}} <- clear_of(pusher, p.radius, {qx, qy}, {tx, ty}, along),
             true <- G.dist(p.x, p.y, sx, sy) <= 2 * G.dist(p.x, p.y, px, py) + 1.0e-3,
             false <- Enum.any?(w.walls, &puck_in_wall?(p, sx, sy, &1)) do
          {:ok, {sx, sy}}
        else
          _ -> :blocked
        end
    end
  end

  # Moves (qx, qy) along the direction (tx, ty) (forwards if `along` > 0, backwards if < 0)
  # until a puck of radius pr there no longer overlaps the pusher disc.
  defp clear_of({cx, cy, cr}, pr, {qx, qy}, {tx, ty}, along) do
    reach = cr + pr + 1.0e-4

    if G.dist(qx, qy, cx, cy) >= reach do
      {:ok, {qx, qy}}
    else
      b = (qx - cx) * tx + (qy - cy) * ty
      c = (qx - cx) * (qx - cx) + (qy - cy) * (qy - cy) - reach * reach
      root = :math.sqrt(max(0.0, b * b - c))

      cond do
        along > 1.0e-9 ->
          s = -b + root
          {:ok, {qx + s * tx, qy + s * ty}}

        along < -1.0e-9 ->
          s = -b - root
          {:ok, {qx + s * tx, qy + s * ty}}

        true ->
          :blocked
      end
    end
  end

  defp puck_in_wall?(p, px, py, seg) do
    reach = p.radius + abs(px - p.x) + abs(py - p.y) + 1.0e-6

    near?(px, py, reach, seg) and
      (G.segments_cross?(p.x, p.y, px, py, seg) or G.dist_segment(px, py, seg) < p.radius)
  end

  defp closest_point(px, py, {ax, ay, bx, by} = seg) do
    {_, t} = G.point_segment(px, py, seg)
    {ax + t * (bx - ax), ay + t * (by - ay)}
  end

  defp unit(dx, dy) do
    d = :math.sqrt(dx * dx + dy * dy)
    if d < 1.0e-12, do: {1.0, 0.0}, else: {dx / d, dy / d}
  end

  ## Sensing

  @doc """
  Reads all of a robot's sensors (see the moduledoc for ranges and units); returns the
  readings and the world with its random stream advanced by the sensor noise.
  """
  @spec sense(t(), id()) :: {readings(), t()}
  def sense(%__MODULE__{} = w, id), do: sense(w, id, @sensors)

  @doc """
  Reads only the sensors named in `which` (keys of `t:readings/0`), as a controller that
  needs only some of them would (a line follower reads `[:line]`): cheaper, and it draws
  noise only for those.
  """
  @spec sense(t(), id(), [atom()]) :: {map(), t()}
  def sense(%__MODULE__{} = w, id, which) do
    r = Map.fetch!(w.robots, id)

    Enum.reduce(which, {%{}, w}, fn
      :ultrasonic, {acc, w} ->
        {v, w} = noisy(w, ultrasonic_cm(w, r), w.noise.ultrasonic, 200)
        {Map.put(acc, :ultrasonic, v), w}

      :colour, {acc, w} ->
        {u, rng} = :rand.uniform_s(w.rng)

        if u < w.noise.colour do
          {c, rng} = :rand.uniform_s(10, rng)
          {Map.put(acc, :colour, c - 1), %{w | rng: rng}}
        else
          {Map.put(acc, :colour, colour(w, r)), %{w | rng: rng}}
        end

      :light, {acc, w} ->
        {ll, w} = noisy(w, light_raw(w, r, 1), w.noise.light, 100)
        {lr, w} = noisy(w, light_raw(w, r, -1), w.noise.light, 100)
        {Map.put(acc, :light, {ll, lr}), w}

      :line, {acc, w} ->
        {fl, w} = noisy(w, line_raw(w, r, 1), w.noise.line, 100)
        {fr, w} = noisy(w, line_raw(w, r, -1), w.noise.line, 100)
        {Map.put(acc, :line, {fl, fr}), w}

      :bumped, {acc, w} ->
        {Map.put(acc, :bumped, r.bumped), w}

      :holding, {acc, w} ->
        {Map.put(acc, :holding, r.held), w}

      :puck_in_gripper, {acc, w} ->
        {Map.put(acc, :puck_in_gripper, r.held != nil or in_zone(w, r) != []), w}
    end)
  end

  defp noisy(w, value, sd, cap) do
    {n, rng} = :rand.normal_s(w.rng)
    {round(max(0.0, min(cap * 1.0, value + sd * n))), %{w | rng: rng}}
  end

  @doc false
  # The noiseless ultrasonic distance in cm (exposed for tests of monotonicity).
  def ultrasonic_cm(w, r) do
    ox = r.x + r.radius * :math.cos(r.theta)
    oy = r.y + r.radius * :math.sin(r.theta)

    d =
      for a <- @us_rays, reduce: @us_range do
        best ->
          dx = :math.cos(r.theta + a)
          dy = :math.sin(r.theta + a)

          walls = for s <- w.walls, t = G.ray_segment(ox, oy, dx, dy, s), do: t

          robots =
            for {oid, o} <- w.robots,
                oid != r.id,
                t = G.ray_circle(ox, oy, dx, dy, o.x, o.y, o.radius),
                do: t

          tall =
            for {_, p} <- w.pucks,
                p.tall,
                t = G.ray_circle(ox, oy, dx, dy, p.x, p.y, p.radius),
                do: t

          Enum.min([best | walls ++ robots ++ tall])
      end

    d * 100.0
  end

  @doc false
  # The noiseless reading of a light sensor (side 1 = left, -1 = right), 5..100 (exposed
  # for the tests of its shape). The bulb is @bulb_height above the sensors; distance and
  # bearing are taken from the robot's centre (see the moduledoc and docs/arena.md).
  def light_raw(%{light: %{on: false}}, _r, _side), do: 5.0

  def light_raw(%{light: l}, r, side) do
    dx = l.x - r.x
    dy = l.y - r.y
    flat = :math.sqrt(dx * dx + dy * dy)
    d = :math.sqrt(flat * flat + @bulb_height * @bulb_height)
    # cosine of the bulb's elevation: 1 far off, 0 right overhead
    c = flat / d
    a = r.theta + side * @light_axis
    cos_phi = if flat < 1.0e-9, do: 1.0, else: (dx * :math.cos(a) + dy * :math.sin(a)) / flat
    facing = (1.0 + cos_phi) / 2
    f = 0.3 + 0.7 * (1.0 - c * (1.0 - facing))
    5.0 + 95.0 * f / (1.0 + d / @light_falloff * (d / @light_falloff))
  end

  @doc false
  # Where a robot's line sensor sits (side 1 = left, -1 = right).
  def line_sensor_point(r, side) do
    c = :math.cos(r.theta)
    s = :math.sin(r.theta)

    {r.x + @line_ahead * c - side * @line_lateral * s,
     r.y + @line_ahead * s + side * @line_lateral * c}
  end

  defp line_raw(w, r, side) do
    {px, py} = line_sensor_point(r, side)
    floor = floor_reflect(w, px, py)

    c =
      if w.line_footprint,
        do: footprint_coverage(w, px, py, w.line_footprint),
        else: line_coverage(w, px, py)

    floor * (1 - c) + @black_reflect * c
  end

  # 32 points spread evenly over a disc of radius 1 (Vogel's sunflower: equal areas)
  @sunflower (for k <- 0..31 do
                rho = :math.sqrt((k + 0.5) / 32)
                a = k * :math.pi() * (3 - :math.sqrt(5))
                {rho * :math.cos(a), rho * :math.sin(a)}
              end)

  @doc false
  # The black fraction of a disc footprint of radius `rad` at (px, py), 0..1: the share
  # of the sunflower's points on a line (within half its width of a segment).
  def footprint_coverage(w, px, py, rad) do
    on =
      Enum.count(@sunflower, fn {u, v} ->
        x = px + rad * u
        y = py + rad * v

        w.line_index
        |> Map.get({cell(x), cell(y)}, [])
        |> Enum.any?(fn {ax, ay, bx, by, width} ->
          G.dist_segment(x, y, {ax, ay, bx, by}) <= width / 2
        end)
      end)

    on / 32
  end

  @doc """
  The distance (m) from `(x, y)` to the nearest black line, or `:infinity` when no line
  is within 5 cm (the floor index only keeps what is near).
  """
  @spec line_distance(t(), number(), number()) :: float() | :infinity
  def line_distance(%__MODULE__{} = w, x, y) do
    w.line_index
    |> Map.get({cell(x), cell(y)}, [])
    |> Enum.reduce(:infinity, fn {ax, ay, bx, by, _}, best ->
      min(best, G.dist_segment(x, y, {ax, ay, bx, by}))
    end)
  end

  @doc false
  # How much of a sensor spot at (px, py) covers black line, 0..1.
  def line_coverage(w, px, py) do
    case Map.get(w.line_index, {cell(px), cell(py)}, []) do
      [] ->
        0.0

      segs ->
        Enum.reduce(segs, 0.0, fn {ax, ay, bx, by, width}, best ->
          d = G.dist_segment(px, py, {ax, ay, bx, by})
          max(best, min(1.0, max(0.0, (width / 2 + @spot - d) / (2 * @spot))))
        end)
    end
  end

  defp floor_reflect(w, px, py) do
    case marker_at(w, px, py) do
      nil -> @floor_reflect
      m -> Map.fetch!(@reflect, m.colour)
    end
  end

  @doc false
  def marker_at(w, px, py) do
    Enum.find(w.markers, fn m -> abs(px - m.x) <= m.w / 2 and abs(py - m.y) <= m.h / 2 end)
  end

  defp colour(w, r) do
    cx = r.x + (r.radius + 0.025) * :math.cos(r.theta)
    cy = r.y + (r.radius + 0.025) * :math.sin(r.theta)

    puck =
      Enum.find(Map.values(w.pucks), fn p -> G.dist(cx, cy, p.x, p.y) <= p.radius + 0.005 end)

    cond do
      puck -> puck.colour
      m = marker_at(w, cx, cy) -> m.colour
      line_coverage(w, cx, cy) > 0.5 -> 0
      true -> 7
    end
  end
end
