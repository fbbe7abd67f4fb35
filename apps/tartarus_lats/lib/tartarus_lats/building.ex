defmodule TartarusLats.Building do
  @moduledoc """
  An emulated multi-floor building: one Pi-node per zone, where each node
  stands, which nodes are neighbours, and where people come in.

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

  defstruct nodes: [],
            positions: %{},
            adjacency: %{},
            entrances: [],
            floor_height: 4.0,
            floor_loss_db: 15.0

  @typedoc "A node (zone) name; `new/1` uses `:p1 .. :pN`."
  @type node_name :: atom()

  @typedoc "A point in metres `{x, y, z}`."
  @type position :: {float(), float(), float()}

  @type t :: %__MODULE__{
          nodes: [node_name()],
          positions: %{node_name() => position()},
          adjacency: %{node_name() => [node_name()]},
          entrances: [node_name()],
          floor_height: float(),
          floor_loss_db: float()
        }

  @doc """
  A grid building. Options (defaults): `floors: 2`, `rows: 5`, `cols: 5`,
  `spacing: 9.0`, `floor_height: 4.0`, `floor_loss_db: 15.0`,
  `stairs: [{0, 0}, {rows - 1, cols - 1}]`, `entrances: [{0, div(cols, 2)}]`
  (`{row, col}` cells on floor 0).

      iex> b = TartarusLats.Building.new(floors: 1, rows: 2, cols: 3)
      iex> TartarusLats.Building.nodes(b)
      [:p1, :p2, :p3, :p4, :p5, :p6]
      iex> TartarusLats.Building.new(rows: 0)
      ** (ArgumentError) invalid options given to TartarusLats.Building.new/1 for key :rows: expected a positive integer, got: 0
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    floors = opt(opts, :floors, 2, &pos_int?/1, "a positive integer")
    rows = opt(opts, :rows, 5, &pos_int?/1, "a positive integer")
    cols = opt(opts, :cols, 5, &pos_int?/1, "a positive integer")
    spacing = opt(opts, :spacing, 9.0, &pos_num?/1, "a positive number")
    floor_height = opt(opts, :floor_height, 4.0, &pos_num?/1, "a positive number")
    floor_loss = opt(opts, :floor_loss_db, 15.0, &(is_number(&1) and &1 >= 0), "a number >= 0")
    cell? = &match?({r, c} when r in 0..(rows - 1) and c in 0..(cols - 1), &1)
    cells? = &(is_list(&1) and Enum.all?(&1, cell?))

    stairs =
      opt(
        opts,
        :stairs,
        Enum.uniq([{0, 0}, {rows - 1, cols - 1}]),
        cells?,
        "a list of {row, col} cells"
      )

    entrances = opt(opts, :entrances, [{0, div(cols, 2)}], cells?, "a list of {row, col} cells")

    if entrances == [] do
      raise ArgumentError,
            "invalid options given to TartarusLats.Building.new/1 for key :entrances: " <>
              "expected at least one entrance, got: []"
    end

    name = fn f, r, c -> :"p#{f * rows * cols + r * cols + c + 1}" end
    cells = for f <- 0..(floors - 1), r <- 0..(rows - 1), c <- 0..(cols - 1), do: {f, r, c}

    positions =
      Map.new(cells, fn {f, r, c} ->
        {name.(f, r, c), {c * spacing * 1.0, r * spacing * 1.0, f * floor_height * 1.0}}
      end)

    adjacency =
      Map.new(cells, fn {f, r, c} ->
        flat = for {dr, dc} <- [{-1, 0}, {0, -1}, {0, 1}, {1, 0}], do: {f, r + dr, c + dc}
        vertical = if {r, c} in stairs, do: [{f - 1, r, c}, {f + 1, r, c}], else: []

        neighbours =
          for {f2, r2, c2} <- flat ++ vertical,
              f2 in 0..(floors - 1) and r2 in 0..(rows - 1) and c2 in 0..(cols - 1),
              do: name.(f2, r2, c2)

        {name.(f, r, c), sort_nodes(neighbours)}
      end)

    %__MODULE__{
      nodes: Enum.map(cells, fn {f, r, c} -> name.(f, r, c) end),
      positions: positions,
      adjacency: adjacency,
      entrances: for({r, c} <- entrances, do: name.(0, r, c)) |> Enum.uniq(),
      floor_height: floor_height * 1.0,
      floor_loss_db: floor_loss * 1.0
    }
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

    edges = for {n, ns} <- adjacency, m <- ns, n != m, pair <- [{n, m}, {m, n}], do: pair

    adj =
      Enum.reduce(edges, Map.new(Map.keys(positions), &{&1, []}), fn {n, m}, acc ->
        Map.update!(acc, n, &[m | &1])
      end)
      |> Map.new(fn {n, ns} -> {n, ns |> Enum.uniq() |> sort_nodes()} end)

    %__MODULE__{
      nodes: positions |> Map.keys() |> sort_nodes(),
      positions: Map.new(positions, fn {n, {x, y, z}} -> {n, {x * 1.0, y * 1.0, z * 1.0}} end),
      adjacency: adj,
      entrances: entrances,
      floor_height: Keyword.get(opts, :floor_height, 4.0) * 1.0,
      floor_loss_db: Keyword.get(opts, :floor_loss_db, 15.0) * 1.0
    }
  end

  @doc "All nodes, in order (`:p1, :p2, ...` for `new/1`)."
  @spec nodes(t()) :: [node_name()]
  def nodes(%__MODULE__{nodes: nodes}), do: nodes

  @doc "The neighbours of a node, in node order."
  @spec neighbours(t(), node_name()) :: [node_name()]
  def neighbours(%__MODULE__{adjacency: adj}, node), do: Map.fetch!(adj, node)

  @doc "The adjacency map `%{node => [node]}`."
  @spec adjacency(t()) :: %{node_name() => [node_name()]}
  def adjacency(%__MODULE__{adjacency: adj}), do: adj

  @doc "The entry/exit nodes."
  @spec entrances(t()) :: [node_name()]
  def entrances(%__MODULE__{entrances: e}), do: e

  @doc "Where a node stands, in metres."
  @spec position(t(), node_name()) :: position()
  def position(%__MODULE__{positions: p}, node), do: Map.fetch!(p, node)

  @doc """
  Euclidean distance in metres between a point and a node.

      iex> b = TartarusLats.Building.new()
      iex> TartarusLats.Building.distance(b, {3.0, 4.0, 0.0}, :p1)
      5.0
  """
  @spec distance(t(), position(), node_name()) :: float()
  def distance(%__MODULE__{} = b, {x, y, z}, node) do
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
  def extra_loss(%__MODULE__{} = b, {_, _, z}, node) do
    {_, _, nz} = position(b, node)
    b.floor_loss_db * abs(z - nz) / b.floor_height
  end

  @doc """
  The node nearest to a point (ties go to the earlier node): the zone the
  point is in.

      iex> TartarusLats.Building.nearest(TartarusLats.Building.new(), {10.0, 1.0, 0.0})
      :p2
  """
  @spec nearest(t(), position()) :: node_name()
  def nearest(%__MODULE__{nodes: nodes} = b, point) do
    Enum.min_by(nodes, &distance(b, point, &1))
  end

  @doc """
  A shortest path (fewest hops, both ends included) between two nodes, or
  `nil` if none. Deterministic: neighbours are explored in node order.

      iex> TartarusLats.Building.shortest_path(TartarusLats.Building.new(), :p1, :p3)
      [:p1, :p2, :p3]
  """
  @spec shortest_path(t(), node_name(), node_name()) :: [node_name()] | nil
  def shortest_path(%__MODULE__{}, from, from), do: [from]

  def shortest_path(%__MODULE__{} = b, from, to) do
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

  defp opt(opts, key, default, valid?, expected) do
    value = Keyword.get(opts, key, default)

    if valid?.(value) do
      value
    else
      raise ArgumentError,
            "invalid options given to TartarusLats.Building.new/1 for key #{inspect(key)}: " <>
              "expected #{expected}, got: #{inspect(value)}"
    end
  end

  defp pos_int?(v), do: is_integer(v) and v > 0
  defp pos_num?(v), do: is_number(v) and v > 0
end
