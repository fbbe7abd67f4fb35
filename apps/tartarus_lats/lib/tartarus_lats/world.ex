defmodule TartarusLats.World do
  @moduledoc """
  The emulated world of the thesis's experiment (§3.4.2): tag bearers walking
  through a `TartarusLats.Building`, and what every node's receiver hears.

  By default there are 10 bearers: 6 random walkers (`:walker1 .. :walker6`)
  and 4 with scripted routes (`:head`, `:professor`, `:janitor`, `:guard`).
  The world is a plain value advanced one second at a time by `step/2`; all
  randomness comes from the explicit `:rand` state you pass in, so a run is
  reproducible from its seed.

      iex> alias TartarusLats.{Radio, World}
      iex> world = World.new()
      iex> rng = Radio.seed(7)
      iex> {world, rng} = Enum.reduce(1..60, {world, rng}, fn _, {w, r} -> World.step(w, r) end)
      iex> World.time(world)
      60
      iex> World.current_zone(world, :guard) in TartarusLats.Building.nodes(world.building)
      true
      iex> {readings, _rng} = World.readings(world, rng)
      iex> map_size(readings)
      50

  ## Movement

  A bearer is outside until its entry time, then appears at an entrance,
  dwells there a few seconds and moves on. Moving means walking in a
  straight line from one node to a neighbouring node at the bearer's speed
  (about 1.2 m/s), passing through intermediate nodes' positions; dwelling
  means standing still within `1.5 m` of a node for some seconds.

    * Random walkers dwell 5–40 s, then walk to a random neighbour; they
      enter at 10, 20, ..., 60 s and never leave.
    * Scripted bearers follow a route of `{node, dwell_seconds}` stops
      (shortest paths between stops), then walk back to their exit and
      leave. `default_scripts/1` derives the routes from any building.

  ## Ground truth

  A bearer inside the building is in the zone of the node nearest to it
  (`current_zone/2`); `visited_path/2` lists the zones in order with the
  second the bearer entered and left each (the last stay has `left_at: nil`
  while it lasts). Trackers see a change a few seconds later (filter window
  and debounce), and the node boundaries are where both neighbouring nodes
  classify the tag as far, so queries should be compared against this path
  with a few seconds of tolerance.
  """

  alias TartarusLats.{Beacon, Building, Radio}

  @uuid "12121212b64445208f0c720eaf059935"
  @max_offset 1.5

  defstruct building: nil, radio: nil, time: 0, names: [], bearers: %{}, paths: %{}

  @typedoc "A bearer's name, e.g. `:head` or `:walker3`."
  @type name :: atom()

  @typedoc "A scripted route."
  @type script :: %{
          name: name(),
          enter_at: non_neg_integer(),
          entrance: Building.node_name(),
          route: [{Building.node_name(), non_neg_integer()}],
          exit: Building.node_name()
        }

  @typedoc "One stay of a bearer in a zone (ground truth)."
  @type stay :: %{zone: Building.node_name(), entered_at: integer(), left_at: integer() | nil}

  @type t :: %__MODULE__{
          building: Building.t(),
          radio: Radio.t(),
          time: integer(),
          names: [name()],
          bearers: %{name() => map()},
          paths: %{name() => [stay()]}
        }

  @doc """
  A new world at time 0.

  Options: `:building` (default `TartarusLats.Building.new/0`), `:radio`
  (default `TartarusLats.Radio.new/0`), `:walkers` (number of random
  walkers, default 6), `:scripts` (default `default_scripts/1`), `:speed`
  (m/s, default 1.2), `:tx_power` (dBm at 1 m, default -59).
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    building = Keyword.get_lazy(opts, :building, &Building.new/0)
    radio = Keyword.get_lazy(opts, :radio, &Radio.new/0)
    walkers = Keyword.get(opts, :walkers, 6)
    scripts = Keyword.get_lazy(opts, :scripts, fn -> default_scripts(building) end)
    speed = Keyword.get(opts, :speed, 1.2)
    tx = Keyword.get(opts, :tx_power, -59)

    Tartarus.Options.validate!(
      [walkers: walkers],
      [walkers: [type: :non_neg_integer]],
      "TartarusLats.World.new/1"
    )

    Enum.each(scripts, &check_script!(building, &1))
    [entrance | _] = Building.entrances(building)

    scripted =
      scripts
      |> Enum.with_index(1)
      |> Enum.map(fn {s, i} ->
        plan =
          Enum.flat_map(s.route, fn {node, dwell} -> [{:goto, node}, {:dwell, dwell}] end) ++
            [{:goto, s.exit}, {:dwell, 3}, :leave]

        bearer(s.name, {@uuid, 1, i}, tx, :scripted, speed, s.enter_at, s.entrance, plan)
      end)

    random =
      for i <- 1..walkers//1 do
        name = :"walker#{i}"
        bearer(name, {@uuid, 2, i}, tx, :random, speed * (0.85 + 0.05 * i), 10 * i, entrance, [])
      end

    all = scripted ++ random
    world = %__MODULE__{building: building, radio: radio, names: Enum.map(all, & &1.name)}
    world = %{world | bearers: Map.new(all, &{&1.name, &1}), paths: Map.new(all, &{&1.name, []})}
    {world, _} = advance_all(world, :rand.seed_s(:exsss, 0), 0.0)
    world
  end

  defp bearer(name, tag, tx, kind, speed, enter_at, entrance, plan) do
    %{
      name: name,
      tag: tag,
      tx_power: tx,
      kind: kind,
      speed: speed,
      state: {:waiting, enter_at, entrance},
      plan: [{:dwell, 3} | plan],
      pos: nil
    }
  end

  defp check_script!(building, script) do
    nodes = MapSet.new(Building.nodes(building))

    valid =
      match?(
        %{name: n, enter_at: t, entrance: _, route: r, exit: _}
        when is_atom(n) and is_integer(t) and t >= 0 and is_list(r),
        script
      ) and
        MapSet.member?(nodes, script.entrance) and MapSet.member?(nodes, script.exit) and
        Enum.all?(
          script.route,
          &match?({node, d} when is_integer(d) and d >= 0 and is_atom(node), &1)
        ) and
        Enum.all?(script.route, fn {node, _} -> MapSet.member?(nodes, node) end)

    unless valid do
      raise ArgumentError,
            "invalid options given to TartarusLats.World.new/1 for key :scripts: expected maps " <>
              "%{name: atom, enter_at: seconds, entrance: node, route: [{node, dwell_seconds}], exit: node} " <>
              "with nodes of the building, got: #{inspect(script)}"
    end

    # People come in through doors: the nodes know which zones have one (a Trace that walks
    # back to an entry elsewhere reports a broken chain, see TartarusLats.Query).
    unless script.entrance in Building.entrances(building) do
      raise ArgumentError,
            "invalid options given to TartarusLats.World.new/1 for key :scripts: expected " <>
              "script #{inspect(script.name)}'s entrance to be one of the building's entrances " <>
              "#{inspect(Building.entrances(building))}, got: #{inspect(script.entrance)}"
    end
  end

  @doc """
  Scripted routes for the Head, Professor, Janitor and Guard in `building`.

  Stops are chosen by their position in the node list, so the scripts fit
  any building: the Head goes to an office near the last node for 10
  minutes, then to a meeting room for 5; the Professor to a lab then a
  classroom; the Janitor cleans eight zones for a minute each; the Guard
  patrols the corners of every floor twice. All enter and leave by the
  first entrance.

      iex> scripts = TartarusLats.World.default_scripts(TartarusLats.Building.new())
      iex> Enum.map(scripts, & &1.name)
      [:head, :professor, :janitor, :guard]
      iex> hd(scripts).route
      [p49: 600, p13: 300]
  """
  @spec default_scripts(Building.t()) :: [script()]
  def default_scripts(building) do
    nodes = Building.nodes(building)
    [door | _] = Building.entrances(building)
    pick = fn frac -> Enum.at(nodes, round(frac * (length(nodes) - 1))) end
    corners = corners(building)

    [
      %{name: :head, enter_at: 20, route: [{pick.(0.98), 600}, {pick.(0.245), 300}]},
      %{name: :professor, enter_at: 60, route: [{pick.(0.8), 400}, {pick.(0.16), 400}]},
      %{
        name: :janitor,
        enter_at: 0,
        route: for(f <- [0.1, 0.45, 0.3, 0.6, 0.9, 0.7, 0.55, 0.2], do: {pick.(f), 60})
      },
      %{name: :guard, enter_at: 5, route: for(c <- corners ++ corners, do: {c, 15})}
    ]
    |> Enum.map(&Map.merge(&1, %{entrance: door, exit: door}))
  end

  # Per floor (by z), the nodes at extreme x/y: bounding-box corners.
  defp corners(building) do
    building
    |> Building.nodes()
    |> Enum.group_by(fn n -> elem(Building.position(building, n), 2) end)
    |> Enum.sort()
    |> Enum.flat_map(fn {_z, nodes} ->
      xy = Enum.map(nodes, &Building.position(building, &1))
      {xs, ys} = {Enum.map(xy, &elem(&1, 0)), Enum.map(xy, &elem(&1, 1))}

      for {x, y} <- [
            {Enum.min(xs), Enum.min(ys)},
            {Enum.max(xs), Enum.min(ys)},
            {Enum.max(xs), Enum.max(ys)},
            {Enum.min(xs), Enum.max(ys)}
          ] do
        Enum.min_by(nodes, fn n ->
          {nx, ny, _} = Building.position(building, n)
          abs(nx - x) + abs(ny - y)
        end)
      end
      |> Enum.uniq()
    end)
  end

  @doc "The current time in seconds."
  @spec time(t()) :: integer()
  def time(%__MODULE__{time: t}), do: t

  @doc "The bearers' names, scripted first."
  @spec names(t()) :: [name()]
  def names(%__MODULE__{names: names}), do: names

  @doc """
  The tag `{uuid, major, minor}` a bearer wears (major 1: scripted staff,
  major 2: random walkers).

      iex> TartarusLats.World.tag(TartarusLats.World.new(), :head)
      {"12121212b64445208f0c720eaf059935", 1, 1}
  """
  @spec tag(t(), name()) :: Beacon.tag_id()
  def tag(%__MODULE__{bearers: b}, name), do: Map.fetch!(b, name).tag

  @doc "The bearer wearing `tag`, or `nil`."
  @spec bearer_of(t(), Beacon.tag_id()) :: name() | nil
  def bearer_of(%__MODULE__{bearers: b, names: names}, tag),
    do: Enum.find(names, &(Map.fetch!(b, &1).tag == tag))

  @doc """
  The beacon a bearer's tag sends (`rssi` set to the given reading), ready
  for `TartarusLats.IBeacon.encode/1`.
  """
  @spec beacon(t(), name(), integer()) :: Beacon.t()
  def beacon(%__MODULE__{} = world, name, rssi) do
    %{tag: {uuid, major, minor}, tx_power: tx} = Map.fetch!(world.bearers, name)
    %Beacon{uuid: uuid, major: major, minor: minor, tx_power: tx, rssi: rssi}
  end

  @doc "A bearer's position in metres, or `:outside`."
  @spec position(t(), name()) :: Building.position() | :outside
  def position(%__MODULE__{bearers: b}, name) do
    case Map.fetch!(b, name).pos do
      nil -> :outside
      pos -> pos
    end
  end

  @doc "The zone (nearest node) a bearer is in now, or `:outside`."
  @spec current_zone(t(), name()) :: Building.node_name() | :outside
  def current_zone(%__MODULE__{paths: paths}, name) do
    case Map.fetch!(paths, name) do
      [%{left_at: nil, zone: zone} | _] -> zone
      _ -> :outside
    end
  end

  @doc "Ground truth: the zones a bearer visited, oldest first, with entry and exit times."
  @spec visited_path(t(), name()) :: [stay()]
  def visited_path(%__MODULE__{paths: paths}, name),
    do: paths |> Map.fetch!(name) |> Enum.reverse()

  @doc """
  Advances the world by one second (bearers move, ground truth is updated).
  """
  @spec step(t(), Radio.rng()) :: {t(), Radio.rng()}
  def step(%__MODULE__{} = world, rng), do: advance_all(%{world | time: world.time + 1}, rng, 1.0)

  @doc """
  What every node hears this second: `%{node => %{tag => rssi | :missing}}`
  for every node and every bearer's tag (`:missing` for bearers outside).
  """
  @spec readings(t(), Radio.rng()) ::
          {%{Building.node_name() => %{Beacon.tag_id() => integer() | :missing}}, Radio.rng()}
  def readings(%__MODULE__{building: b} = world, rng) do
    bearers = Enum.map(world.names, &Map.fetch!(world.bearers, &1))

    Enum.map_reduce(Building.nodes(b), rng, fn node, rng ->
      {pairs, rng} =
        Enum.map_reduce(bearers, rng, fn
          %{pos: nil, tag: tag}, rng ->
            {{tag, :missing}, rng}

          %{pos: pos, tag: tag, tx_power: tx}, rng ->
            d = Building.distance(b, pos, node)

            {value, rng} =
              Radio.sample(world.radio, d, tx, rng, Building.extra_loss(b, pos, node))

            {{tag, value}, rng}
        end)

      {{node, Map.new(pairs)}, rng}
    end)
    |> then(fn {list, rng} -> {Map.new(list), rng} end)
  end

  # -- movement ---------------------------------------------------------------

  defp advance_all(world, rng, dt) do
    {world, rng} =
      Enum.reduce(world.names, {world, rng}, fn name, {world, rng} ->
        {bearer, rng} = advance(world, Map.fetch!(world.bearers, name), dt, rng, 20)
        bearer = %{bearer | pos: position_of(world.building, bearer)}
        {%{world | bearers: Map.put(world.bearers, name, bearer)}, rng}
      end)

    {update_paths(world), rng}
  end

  defp advance(_world, bearer, _dt, rng, 0), do: {bearer, rng}

  defp advance(world, %{state: {:waiting, at, entrance}} = b, dt, rng, n) do
    if world.time >= at, do: next_action(world, b, entrance, dt, rng, n), else: {b, rng}
  end

  defp advance(_world, %{state: :gone} = b, _dt, rng, _n), do: {b, rng}

  defp advance(world, %{state: {:dwell, node, until, _offset}} = b, dt, rng, n) do
    if world.time >= until, do: next_action(world, b, node, dt, rng, n), else: {b, rng}
  end

  defp advance(world, %{state: {:walk, from, to, travelled, length}} = b, dt, rng, n) do
    travelled = travelled + b.speed * dt

    if travelled >= length do
      left = (travelled - length) / b.speed
      next_action(world, %{b | state: {:at, to}}, to, left, rng, n)
    else
      {%{b | state: {:walk, from, to, travelled, length}}, rng}
    end
  end

  defp next_action(world, %{kind: :random, plan: []} = b, node, dt, rng, n) do
    neighbours = Building.neighbours(world.building, node)
    {i, rng} = :rand.uniform_s(max(length(neighbours), 1), rng)
    {dwell, rng} = :rand.uniform_s(36, rng)
    plan = if neighbours == [], do: [], else: [{:goto, Enum.at(neighbours, i - 1)}]
    next_action(world, %{b | plan: plan ++ [{:dwell, dwell + 4}]}, node, dt, rng, n - 1)
  end

  defp next_action(world, %{plan: [{:goto, node} | plan]} = b, node, dt, rng, n),
    do: next_action(world, %{b | plan: plan}, node, dt, rng, n - 1)

  defp next_action(world, %{plan: [{:goto, target} | _]} = b, node, dt, rng, n) do
    [^node, hop | _] = Building.shortest_path(world.building, node, target)
    length = Building.distance(world.building, Building.position(world.building, node), hop)
    advance(world, %{b | state: {:walk, node, hop, 0.0, length}}, dt, rng, n - 1)
  end

  defp next_action(world, %{plan: [{:dwell, secs} | plan]} = b, node, _dt, rng, _n) do
    {u1, rng} = :rand.uniform_s(rng)
    {u2, rng} = :rand.uniform_s(rng)

    offset =
      {@max_offset * u1 * :math.cos(2 * :math.pi() * u2),
       @max_offset * u1 * :math.sin(2 * :math.pi() * u2)}

    {%{b | plan: plan, state: {:dwell, node, world.time + secs, offset}}, rng}
  end

  defp next_action(_world, %{plan: [:leave | _]} = b, _node, _dt, rng, _n),
    do: {%{b | plan: [], state: :gone}, rng}

  defp next_action(_world, %{plan: []} = b, node, _dt, rng, _n),
    do: {%{b | state: {:dwell, node, :infinity, {0.0, 0.0}}}, rng}

  defp position_of(_building, %{state: {:waiting, _, _}}), do: nil
  defp position_of(_building, %{state: :gone}), do: nil

  defp position_of(building, %{state: {:dwell, node, _, {dx, dy}}}) do
    {x, y, z} = Building.position(building, node)
    {x + dx, y + dy, z}
  end

  defp position_of(building, %{state: {:walk, from, to, travelled, length}}) do
    {x1, y1, z1} = Building.position(building, from)
    {x2, y2, z2} = Building.position(building, to)
    f = if length > 0, do: min(travelled / length, 1.0), else: 1.0
    {x1 + f * (x2 - x1), y1 + f * (y2 - y1), z1 + f * (z2 - z1)}
  end

  defp update_paths(world) do
    paths =
      Map.new(world.names, fn name ->
        pos = Map.fetch!(world.bearers, name).pos
        zone = if pos, do: Building.nearest(world.building, pos), else: :outside
        path = Map.fetch!(world.paths, name)

        path =
          case path do
            [%{left_at: nil, zone: ^zone} | _] ->
              path

            [%{left_at: nil} = open | rest] ->
              closed = [%{open | left_at: world.time} | rest]
              if zone == :outside, do: closed, else: [stay(zone, world.time) | closed]

            _ ->
              if zone == :outside, do: path, else: [stay(zone, world.time) | path]
          end

        {name, path}
      end)

    %{world | paths: paths}
  end

  defp stay(zone, t), do: %{zone: zone, entered_at: t, left_at: nil}
end
