defmodule TartarusLats.Building do
  @moduledoc """
  An emulated multi-floor building: one Pi-node per zone, where each node
  stands, which nodes are neighbours, and where people come in.

  A building **is** a `TartarusEmu.Topology` (kind `:building`): its nodes
  and edges are the Pi-nodes and the corridors between zones, `positions`
  are 3-D points in metres, `floors` the floor of each node, `zones` map
  every node to its own zone (one node per zone), and `attrs` hold
  `:entrances`, `:floor_height` and `:floor_loss_db`. So the same value
  starts the hosts (`TartarusEmu.Network.start/2`) and drives the world
  (`TartarusLats.World`). The functions here read those fields; neighbours
  come in node order (`:p2` before `:p10`).

  The default (`new/0`) reproduces the thesis's experiment size (§3.4.2): 50
  nodes on 2 floors of 5 x 5 zones. Zones are 9 m apart, so a tag standing
  in a zone is near (< 2 m) or far (< 5 m) from its own node and more than
  5 m from every other node, while a tag walking between two neighbouring
  nodes passes the 4.5 m midpoint where both see it as far: the overlap the
  motion-vector handshake relies on.

      iex> b = TartarusLats.Building.new()
      iex> length(TartarusLats.Building.nodes(b))
      50
      iex> TartarusLats.Building.neighbours(b, :p1)
      [:p2, :p6, :p26]
      iex> TartarusLats.Building.entrances(b)
      [:p3]
      iex> TartarusLats.Building.position(b, :p7)
      {9.0, 9.0, 0.0}

  ## Layout of `new/1`

    * Node names are atoms `:p1 .. :pN`, numbered floor by floor, row by row:
      on a `rows x cols` floor, the node at `{floor, row, col}` (all
      0-based) is `:"p\#{floor * rows * cols + row * cols + col + 1}"`.
    * Position of that node in metres: `{col * spacing, row * spacing,
      floor * floor_height}`.
    * Each floor is an open grid: a node's neighbours are the nodes one
      step up, down, left or right (corridors between zones).
    * Stairs link the same grid cell on consecutive floors, at the cells
      given by `:stairs` (default: two opposite corners, `[{0, 0}, {rows-1,
      cols-1}]`).
    * People enter and leave through the `:entrances` cells on floor 0
      (default: the middle of the first row, i.e. `:p3`).
    * Floors attenuate: a node hears a tag on another floor with an extra
      `floor_loss_db` per floor of height difference (default 15 dB).

  Any other plan can be given to `custom/1`.
  """

  alias TartarusEmu.Topology

  @typedoc "A node (zone) name; `new/1` uses `:p1 .. :pN`."
  @type node_name :: atom()

  @typedoc "A point in metres `{x, y, z}`."
  @type position :: {float(), float(), float()}

  @typedoc "A building: a `TartarusEmu.Topology` of kind `:building` (see the moduledoc)."
  @type t :: Topology.t()

  @schema [
    floors: [type: :pos_integer, default: 2, doc: "floors"],
    rows: [type: :pos_integer, default: 5, doc: "rows of zones per floor"],
    cols: [type: :pos_integer, default: 5, doc: "columns of zones per floor"],
    spacing: [type: :any, default: 9.0, check: :positive, doc: "metres between zones"],
    floor_height: [type: :any, default: 4.0, check: :positive, doc: "metres between floors"],
    floor_loss_db: [
      type: :any,
      default: 15.0,
      check: :at_least_zero,
      doc: "extra attenuation per floor (dB)"
    ],
    stairs: [type: {:list, :any}, doc: "`{row, col}` cells with stairs"],
    entrances: [type: {:list, :any}, doc: "`{row, col}` cells on floor 0 where people enter"]
  ]

  @doc """
  A grid building. Options:

  #{Tartarus.Options.docs(@schema)}

  `stairs` defaults to `[{0, 0}, {rows - 1, cols - 1}]`, `entrances` to
  `[{0, div(cols, 2)}]`.

      iex> b = TartarusLats.Building.new(floors: 1, rows: 2, cols: 3)
      iex> TartarusLats.Building.nodes(b)
      [:p1, :p2, :p3, :p4, :p5, :p6]
      iex> TartarusLats.Building.new(rows: 0)
      ** (ArgumentError) invalid options given to TartarusLats.Building.new/1 for key :rows: expected a positive integer, got: 0
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    where = "TartarusLats.Building.new/1"
    opts = TartarusLats.Options.validate!(opts, @schema, where)
    [floors, rows, cols] = Enum.map([:floors, :rows, :cols], &opts[&1])

    [spacing, floor_height, floor_loss] =
      Enum.map([:spacing, :floor_height, :floor_loss_db], &opts[&1])

    cell? = &match?({r, c} when r in 0..(rows - 1) and c in 0..(cols - 1), &1)
    opts = Keyword.put_new(opts, :stairs, Enum.uniq([{0, 0}, {rows - 1, cols - 1}]))
    opts = Keyword.put_new(opts, :entrances, [{0, div(cols, 2)}])
    stairs = check!(opts, :stairs, &Enum.all?(&1, cell?), "a list of {row, col} cells", where)

    entrances =
      check!(
        opts,
        :entrances,
        &(&1 != [] and Enum.all?(&1, cell?)),
        "a non-empty list of {row, col} cells",
        where
      )

    name = fn f, r, c -> :"p#{f * rows * cols + r * cols + c + 1}" end
    cells = for f <- 0..(floors - 1), r <- 0..(rows - 1), c <- 0..(cols - 1), do: {f, r, c}

    positions =
      Map.new(cells, fn {f, r, c} ->
        {name.(f, r, c), {c * spacing * 1.0, r * spacing * 1.0, f * floor_height * 1.0}}
      end)

    edges =
      for {f, r, c} <- cells,
          {f2, r2, c2} <-
            [{f, r, c + 1}, {f, r + 1, c}] ++ if({r, c} in stairs, do: [{f + 1, r, c}], else: []),
          f2 < floors and r2 < rows and c2 < cols,
          do: {name.(f, r, c), name.(f2, r2, c2)}

    nodes = Enum.map(cells, fn {f, r, c} -> name.(f, r, c) end)

    Topology.new(nodes, edges,
      positions: positions,
      floors: Map.new(cells, fn {f, r, c} -> {name.(f, r, c), f} end),
      zones: Map.new(nodes, &{&1, &1}),
      attrs: %{
        entrances: for({r, c} <- entrances, do: name.(0, r, c)) |> Enum.uniq(),
        floor_height: floor_height * 1.0,
        floor_loss_db: floor_loss * 1.0
      },
      kind: :building
    )
  end

  @doc """
  A building from an explicit plan.

  Required: `:positions` (`%{node => {x, y, z}}` in metres), `:adjacency`
  (`%{node => [node]}`, made symmetric), `:entrances` (a non-empty list of
  nodes). Optional: `:floor_height` (4.0), `:floor_loss_db` (15.0). Raises
  `ArgumentError` on an unknown node or a malformed value.

      iex> b = TartarusLats.Building.custom(
      ...>   positions: %{a: {0, 0, 0}, b: {9, 0, 0}},
      ...>   adjacency: %{a: [:b]},
      ...>   entrances: [:a])
      iex> TartarusLats.Building.neighbours(b, :b)
      [:a]
  """
  @spec custom(keyword()) :: t()
  def custom(opts) do
    positions = Keyword.get(opts, :positions)

    unless is_map(positions) and map_size(positions) > 0 and
             Enum.all?(
               positions,
               &match?({_, {x, y, z}} when is_number(x) and is_number(y) and is_number(z), &1)
             ) do
      raise ArgumentError,
            "invalid options given to TartarusLats.Building.custom/1 for key :positions: " <>
              "expected a non-empty map of node => {x, y, z}, got: #{inspect(positions)}"
    end

    known? = &Map.has_key?(positions, &1)
    adjacency = Keyword.get(opts, :adjacency, %{})

    unless is_map(adjacency) and
             Enum.all?(adjacency, fn {n, ns} ->
               known?.(n) and is_list(ns) and Enum.all?(ns, known?)
             end) do
      raise ArgumentError,
            "invalid options given to TartarusLats.Building.custom/1 for key :adjacency: " <>
              "expected a map of known node => [known node], got: #{inspect(adjacency)}"
    end

    entrances = Keyword.get(opts, :entrances)

    unless is_list(entrances) and entrances != [] and Enum.all?(entrances, known?) do
      raise ArgumentError,
            "invalid options given to TartarusLats.Building.custom/1 for key :entrances: " <>
              "expected a non-empty list of known nodes, got: #{inspect(entrances)}"
    end

    edges =
      for {n, ns} <- adjacency,
          m <- ns,
          n != m,
          uniq: true,
          do: if(n < m, do: {n, m}, else: {m, n})

    floor_height = Keyword.get(opts, :floor_height, 4.0) * 1.0
    nodes = positions |> Map.keys() |> sort_nodes()

    points = Map.new(positions, fn {n, {x, y, z}} -> {n, {x * 1.0, y * 1.0, z * 1.0}} end)

    Topology.new(nodes, edges,
      positions: points,
      floors: Map.new(points, fn {n, {_, _, z}} -> {n, round(z / floor_height)} end),
      zones: Map.new(nodes, &{&1, &1}),
      attrs: %{
        entrances: entrances,
        floor_height: floor_height,
        floor_loss_db: Keyword.get(opts, :floor_loss_db, 15.0) * 1.0
      },
      kind: :building
    )
  end

  @doc "All nodes, in order (`:p1, :p2, ...` for `new/1`)."
  @spec nodes(t()) :: [node_name()]
  def nodes(%Topology{nodes: nodes}), do: nodes

  @doc "The neighbours of a node, in node order."
  @spec neighbours(t(), node_name()) :: [node_name()]
  def neighbours(%Topology{} = b, node) do
    unless Map.has_key?(b.positions, node), do: raise(KeyError, key: node, term: b.positions)
    b |> Topology.neighbours(node) |> sort_nodes()
  end

  @doc "The adjacency map `%{node => [node]}`."
  @spec adjacency(t()) :: %{node_name() => [node_name()]}
  def adjacency(%Topology{} = b),
    do: b |> Topology.adjacency() |> Map.new(fn {n, ns} -> {n, sort_nodes(ns)} end)

  @doc "The entry/exit nodes."
  @spec entrances(t()) :: [node_name()]
  def entrances(%Topology{attrs: %{entrances: e}}), do: e

  @doc "Where a node stands, in metres."
  @spec position(t(), node_name()) :: position()
  def position(%Topology{positions: p}, node), do: Map.fetch!(p, node)

  @doc """
  Euclidean distance in metres between a point and a node.

      iex> b = TartarusLats.Building.new()
      iex> TartarusLats.Building.distance(b, {3.0, 4.0, 0.0}, :p1)
      5.0
  """
  @spec distance(t(), position(), node_name()) :: float()
  def distance(%Topology{} = b, {x, y, z}, node) do
    {nx, ny, nz} = position(b, node)
    :math.sqrt((x - nx) * (x - nx) + (y - ny) * (y - ny) + (z - nz) * (z - nz))
  end

  @doc """
  Extra attenuation in dB between a point and a node from the floors in
  between: `floor_loss_db` per `floor_height` of height difference.

      iex> b = TartarusLats.Building.new()
      iex> TartarusLats.Building.extra_loss(b, {0.0, 0.0, 0.0}, :p26)
      15.0
  """
  @spec extra_loss(t(), position(), node_name()) :: float()
  def extra_loss(%Topology{} = b, {_, _, z}, node) do
    {_, _, nz} = position(b, node)
    b.attrs.floor_loss_db * abs(z - nz) / b.attrs.floor_height
  end

  @doc """
  The node nearest to a point (ties go to the earlier node): the zone the
  point is in.

      iex> TartarusLats.Building.nearest(TartarusLats.Building.new(), {10.0, 1.0, 0.0})
      :p2
  """
  @spec nearest(t(), position()) :: node_name()
  def nearest(%Topology{nodes: nodes} = b, point) do
    Enum.min_by(nodes, &distance(b, point, &1))
  end

  @doc """
  A shortest path (fewest hops, both ends included) between two nodes, or
  `nil` if none. Deterministic: neighbours are explored in node order.

      iex> TartarusLats.Building.shortest_path(TartarusLats.Building.new(), :p1, :p3)
      [:p1, :p2, :p3]
  """
  @spec shortest_path(t(), node_name(), node_name()) :: [node_name()] | nil
  def shortest_path(%Topology{}, from, from), do: [from]

  def shortest_path(%Topology{} = b, from, to) do
    bfs(b, :queue.from_list([from]), %{from => nil}, to)
  end

  defp bfs(b, queue, parents, to) do
    case :queue.out(queue) do
      {:empty, _} ->
        nil

      {{:value, node}, queue} ->
        next = for n <- neighbours(b, node), not Map.has_key?(parents, n), do: n
        parents = Enum.reduce(next, parents, &Map.put(&2, &1, node))

        if Map.has_key?(parents, to) do
          unwind(parents, to, [])
        else
          bfs(b, Enum.reduce(next, queue, &:queue.in/2), parents, to)
        end
    end
  end

  defp unwind(_parents, nil, acc), do: acc
  defp unwind(parents, node, acc), do: unwind(parents, Map.fetch!(parents, node), [node | acc])

  # :p2 before :p10: numeric order for pN names, term order otherwise.
  defp sort_nodes(nodes), do: Enum.sort_by(nodes, &node_key/1)

  defp node_key(node) when is_atom(node) do
    case Atom.to_string(node) do
      "p" <> digits ->
        case Integer.parse(digits) do
          {n, ""} -> {0, n}
          _ -> {1, node}
        end

      _ ->
        {1, node}
    end
  end

  defp node_key(node), do: {2, node}

  defp check!(opts, key, valid?, expected, where) do
    value = opts[key]

    if valid?.(value) do
      value
    else
      raise ArgumentError, TartarusLats.Options.message(where, key, expected, value)
    end
  end
end
