defmodule TartarusEmu.Topology do
  @moduledoc """
  Network topologies for emulation: plain data, built by pure functions.

  A topology is an undirected graph of host names with optional positions, floors, zones,
  per-link attributes and application attributes: the one graph type of the emulator and of
  the applications on it (a LATS building is a topology, see `TartarusLats.Building`). Scenarios build one, then start a host per node and give each host
  its `neighbours/2` as its overlay neighbour set.

      iex> topo = TartarusEmu.Topology.grid(2, 3)
      iex> TartarusEmu.Topology.size(topo)
      6
      iex> TartarusEmu.Topology.neighbours(topo, :h1)
      [:h2, :h4]
      iex> TartarusEmu.Topology.diameter(topo)
      3

  ## The struct

    * `nodes` - node names in a stable order (`:h1, :h2, ...` for generated topologies);
    * `edges` - a `MapSet` of `{a, b}` with `a < b` (Erlang term order), so each undirected
      edge appears once;
    * `positions` - `%{name => {x, y}}` or `%{name => {x, y, z}}` floats (metres, or plot
      units), for plots and for applications that place things in space (may be partial or
      empty);
    * `floors` - `%{name => integer}` for floor plans (may be empty);
    * `zones` - `%{name => zone}`: the zone (room, aisle, area) a node stands for or belongs
      to; several nodes may share one (may be empty);
    * `attrs` - `%{atom => term}`: attributes of the whole topology an application keeps
      with it (e.g. a building's entrances and floor height; may be empty);
    * `links` - `%{{a, b} => %{latency_ms: number, loss: float}}` for edges with explicit
      attributes; `fetch_link/3` fills in the defaults (`latency_ms: 0`, `loss: 0.0`);
    * `kind` - how it was made: `:line`, `:ring`, `:grid`, `:random_geometric`, `:file` or
      `:custom`.

  ## Builders

  `line/1`, `ring/1`, `grid/2` and `random_geometric/4` name nodes `:h1..:hN` (atoms created
  from a bounded counter, never from input). `new/3` builds any graph from lists.
  `parse/2` and `from_file/2` read the text format below.

  ## Floor-plan file format

  One directive per line; `#` starts a comment that runs to the end of the line; blank lines
  are ignored; tokens are separated by spaces or tabs.

      # second floor of the lab
      floor 2                         # following nodes are on floor 2
      node lobby 0 0                  # node NAME [X Y [Z]] [floor F] [zone Z]
      node lab-1 4.5 0 zone lab       # node NAME [X Y [Z]] [floor F] [zone Z]
      node stairs 9 0 4 floor 1       # an explicit floor overrides the section
      edge lobby lab-1                # edge A B [latency_ms=N] [loss=P]
      edge lab-1 stairs latency_ms=12 loss=0.05

    * `node NAME [X Y [Z]] [floor F] [zone Z]` declares a node. `NAME` is 1 to 64
      characters from `A-Z a-z 0-9 _ - . :`. `X Y` (and an optional height `Z`) are numbers
      (position). `F` is an integer. `zone Z` names the node's zone (a string, like
      names).
    * `floor F` starts a floor section: nodes declared after it without their own `floor F`
      get floor `F`, until the next `floor` line.
    * `edge A B [latency_ms=N] [loss=P]` declares an undirected link between two declared
      nodes (they may be declared later in the file). `N` is a non-negative number of
      milliseconds, `P` a probability in `[0, 1]`. Self-loops and repeated edges are errors.

  Anything else (an unknown directive or attribute, a bad number, a duplicate node, an edge
  to an undeclared node) gives `{:error, "line N: ..."}` naming the line, what was expected
  and what arrived.

  **Node names from a file stay strings.** Atoms are never garbage collected, so the parser
  never creates them from file contents. Pass `names: %{"lobby" => :lobby, ...}` to map file
  names to atoms you chose; a name missing from the mapping is then an error.
  """

  @enforce_keys [:nodes, :edges]
  defstruct nodes: [],
            edges: MapSet.new(),
            positions: %{},
            floors: %{},
            zones: %{},
            attrs: %{},
            links: %{},
            kind: :custom

  @typedoc "A node name: an atom for generated topologies, a string for parsed ones."
  @type name :: atom | String.t()

  @typedoc "An undirected edge, smaller name first."
  @type edge :: {name, name}

  @typedoc "Attributes of one link."
  @type link_attrs :: %{latency_ms: number, loss: float}

  @typedoc "A position: `{x, y}` or `{x, y, z}`."
  @type position :: {float, float} | {float, float, float}

  @type t :: %__MODULE__{
          nodes: [name],
          edges: MapSet.t(edge),
          positions: %{optional(name) => position},
          floors: %{optional(name) => integer},
          zones: %{optional(name) => term},
          attrs: %{optional(atom) => term},
          links: %{optional(edge) => link_attrs},
          kind: atom
        }

  @default_link %{latency_ms: 0, loss: 0.0}

  ## Generic construction and queries

  @doc """
  Builds a topology from a list of nodes and a list of `{a, b}` edges (any order).

  Options: `:positions`, `:floors`, `:zones`, `:attrs`, `:links` (maps as in the struct;
  link keys in any order), `:kind` (default `:custom`). Raises `ArgumentError` for edges to unknown nodes, self-loops
  or duplicate nodes.

  ## Examples

      iex> topo = TartarusEmu.Topology.new([:a, :b, :c], [{:b, :a}, {:b, :c}])
      iex> topo.edges
      MapSet.new([{:a, :b}, {:b, :c}])
  """
  @spec new([name], [{name, name}], keyword) :: t
  def new(nodes, edges, opts \\ []) when is_list(nodes) and is_list(edges) do
    node_set = MapSet.new(nodes)

    if MapSet.size(node_set) != length(nodes) do
      dup = nodes -- MapSet.to_list(node_set)

      raise ArgumentError,
            "Topology.new/3: expected unique node names, got duplicates: #{inspect(Enum.uniq(dup))}"
    end

    edge_set =
      MapSet.new(edges, fn {a, b} = edge ->
        cond do
          a == b ->
            raise ArgumentError, "Topology.new/3: expected no self-loops, got: #{inspect(edge)}"

          not (MapSet.member?(node_set, a) and MapSet.member?(node_set, b)) ->
            raise ArgumentError,
                  "Topology.new/3: expected edges between listed nodes, got: #{inspect(edge)}"

          true ->
            norm(a, b)
        end
      end)

    links = Map.new(Keyword.get(opts, :links, %{}), fn {{a, b}, attrs} -> {norm(a, b), attrs} end)

    %__MODULE__{
      nodes: nodes,
      edges: edge_set,
      positions: Keyword.get(opts, :positions, %{}),
      floors: Keyword.get(opts, :floors, %{}),
      zones: Keyword.get(opts, :zones, %{}),
      attrs: Keyword.get(opts, :attrs, %{}),
      links: links,
      kind: Keyword.get(opts, :kind, :custom)
    }
  end

  @doc """
  Returns the sorted neighbours of `node` (`[]` for an unknown or isolated node).

  This scans every edge; to get the neighbours of all nodes, call `adjacency/1` once.

  ## Examples

      iex> TartarusEmu.Topology.line(3) |> TartarusEmu.Topology.neighbours(:h2)
      [:h1, :h3]
  """
  @spec neighbours(t, name) :: [name]
  def neighbours(%__MODULE__{edges: edges}, node) do
    edges
    |> Enum.flat_map(fn
      {^node, other} -> [other]
      {other, ^node} -> [other]
      _ -> []
    end)
    |> Enum.sort()
  end

  @doc """
  Returns `%{node => sorted neighbours}` for every node, isolated ones included.

  ## Examples

      iex> TartarusEmu.Topology.line(3) |> TartarusEmu.Topology.adjacency()
      %{h1: [:h2], h2: [:h1, :h3], h3: [:h2]}
  """
  @spec adjacency(t) :: %{optional(name) => [name]}
  def adjacency(%__MODULE__{nodes: nodes, edges: edges}) do
    empty = Map.new(nodes, &{&1, []})

    edges
    |> Enum.reduce(empty, fn {a, b}, acc ->
      acc |> Map.update!(a, &[b | &1]) |> Map.update!(b, &[a | &1])
    end)
    |> Map.new(fn {node, ns} -> {node, Enum.sort(ns)} end)
  end

  @doc """
  Number of nodes.

  ## Examples

      iex> TartarusEmu.Topology.ring(5) |> TartarusEmu.Topology.size()
      5
  """
  @spec size(t) :: non_neg_integer
  def size(%__MODULE__{nodes: nodes}), do: length(nodes)

  @doc """
  Number of (undirected) edges.

  ## Examples

      iex> TartarusEmu.Topology.ring(5) |> TartarusEmu.Topology.edge_count()
      5
  """
  @spec edge_count(t) :: non_neg_integer
  def edge_count(%__MODULE__{edges: edges}), do: MapSet.size(edges)

  @doc """
  Returns the attributes of the link between `a` and `b` (either order), defaults filled in,
  or `:error` when there is no such edge.

  ## Examples

      iex> TartarusEmu.Topology.line(2) |> TartarusEmu.Topology.fetch_link(:h2, :h1)
      {:ok, %{latency_ms: 0, loss: 0.0}}
      iex> TartarusEmu.Topology.line(3) |> TartarusEmu.Topology.fetch_link(:h1, :h3)
      :error
  """
  @spec fetch_link(t, name, name) :: {:ok, link_attrs} | :error
  def fetch_link(%__MODULE__{edges: edges, links: links}, a, b) do
    edge = norm(a, b)

    if MapSet.member?(edges, edge) do
      {:ok, Map.merge(@default_link, Map.get(links, edge, %{}))}
    else
      :error
    end
  end

  @doc """
  True when every node can reach every other one. The empty topology is connected.

  ## Examples

      iex> TartarusEmu.Topology.connected?(TartarusEmu.Topology.ring(4))
      true
      iex> TartarusEmu.Topology.connected?(TartarusEmu.Topology.new([:a, :b], []))
      false
  """
  @spec connected?(t) :: boolean
  def connected?(%__MODULE__{nodes: []}), do: true

  def connected?(%__MODULE__{nodes: [first | _] = nodes} = topo) do
    map_size(bfs(adjacency(topo), first)) == length(nodes)
  end

  @doc """
  The longest shortest path in hops (BFS from every node); `:infinity` when the topology is
  not connected, `0` for zero or one node.

  ## Examples

      iex> TartarusEmu.Topology.diameter(TartarusEmu.Topology.line(5))
      4
      iex> TartarusEmu.Topology.diameter(TartarusEmu.Topology.new([:a, :b], []))
      :infinity
  """
  @spec diameter(t) :: non_neg_integer | :infinity
  def diameter(%__MODULE__{nodes: nodes} = topo) do
    if connected?(topo) do
      adj = adjacency(topo)

      nodes
      |> Enum.map(fn n -> adj |> bfs(n) |> Map.values() |> Enum.max() end)
      |> Enum.max(fn -> 0 end)
    else
      :infinity
    end
  end

  @doc """
  Hop distances from `source` to every node it reaches (`%{node => hops}`).

  ## Examples

      iex> TartarusEmu.Topology.line(3) |> TartarusEmu.Topology.distances(:h1)
      %{h1: 0, h2: 1, h3: 2}
  """
  @spec distances(t, name) :: %{optional(name) => non_neg_integer}
  def distances(%__MODULE__{} = topo, source) do
    if source in topo.nodes, do: bfs(adjacency(topo), source), else: %{}
  end

  defp bfs(adj, source), do: bfs(adj, :queue.from_list([source]), %{source => 0})

  defp bfs(adj, queue, seen) do
    case :queue.out(queue) do
      {:empty, _} ->
        seen

      {{:value, node}, queue} ->
        d = Map.fetch!(seen, node)

        {queue, seen} =
          Enum.reduce(Map.get(adj, node, []), {queue, seen}, fn n, {q, s} ->
            if Map.has_key?(s, n), do: {q, s}, else: {:queue.in(n, q), Map.put(s, n, d + 1)}
          end)

        bfs(adj, queue, seen)
    end
  end

  defp norm(a, b) when a < b, do: {a, b}
  defp norm(a, b), do: {b, a}

  ## Generated topologies

  @doc """
  `n` nodes in a row, `:h1 - :h2 - ... - :hN`, at positions `{i - 1, 0}`.

  ## Examples

      iex> TartarusEmu.Topology.line(3).edges
      MapSet.new([{:h1, :h2}, {:h2, :h3}])
  """
  @spec line(pos_integer) :: t
  def line(n) do
    check_count!(:line, n, 1)
    names = names(n)
    edges = Enum.zip(names, tl(names) ++ [nil]) |> Enum.reject(&(elem(&1, 1) == nil))
    positions = names |> Enum.with_index() |> Map.new(fn {h, i} -> {h, {i * 1.0, 0.0}} end)
    new(names, edges, positions: positions, kind: :line)
  end

  @doc """
  `n >= 3` nodes in a cycle, placed on the unit circle.

  ## Examples

      iex> topo = TartarusEmu.Topology.ring(4)
      iex> TartarusEmu.Topology.neighbours(topo, :h1)
      [:h2, :h4]
  """
  @spec ring(pos_integer) :: t
  def ring(n) do
    check_count!(:ring, n, 3)
    names = names(n)
    edges = Enum.zip(names, tl(names) ++ [hd(names)])

    positions =
      names
      |> Enum.with_index()
      |> Map.new(fn {h, i} ->
        angle = 2 * :math.pi() * i / n
        {h, {:math.cos(angle), :math.sin(angle)}}
      end)

    new(names, edges, positions: positions, kind: :ring)
  end

  @doc """
  A `rows x cols` grid with 4-neighbour links. Nodes are numbered row by row:
  `:h1` is row 0 column 0, `:h(cols + 1)` is row 1 column 0; node `h` sits at `{col, row}`.

  ## Examples

      iex> topo = TartarusEmu.Topology.grid(3, 3)
      iex> {TartarusEmu.Topology.edge_count(topo), TartarusEmu.Topology.neighbours(topo, :h5)}
      {12, [:h2, :h4, :h6, :h8]}
  """
  @spec grid(pos_integer, pos_integer) :: t
  def grid(rows, cols) do
    check_count!(:grid, rows, 1)
    check_count!(:grid, cols, 1)
    name = fn r, c -> :"h#{r * cols + c + 1}" end

    cells = for r <- 0..(rows - 1), c <- 0..(cols - 1), do: {r, c}

    edges =
      Enum.flat_map(cells, fn {r, c} ->
        right = if c + 1 < cols, do: [{name.(r, c), name.(r, c + 1)}], else: []
        down = if r + 1 < rows, do: [{name.(r, c), name.(r + 1, c)}], else: []
        right ++ down
      end)

    positions = Map.new(cells, fn {r, c} -> {name.(r, c), {c * 1.0, r * 1.0}} end)
    new(names(rows * cols), edges, positions: positions, kind: :grid)
  end

  @doc """
  A random geometric graph: `n` nodes placed uniformly in the unit square, linked when their
  Euclidean distance is at most `radius`.

  `seed` is an integer or a `:rand` state; the draw uses its own `:exsss` state
  (`:rand.seed_s/2`) and never touches the process's global random state, so the same
  seed always gives the same graph.

  Options:
    * `connected: true` - redraw (continuing the same random stream) until the graph is
      connected; raises `ArgumentError` after `:max_attempts` draws (default 1000).

  ## Examples

      iex> a = TartarusEmu.Topology.random_geometric(20, 0.4, 7, connected: true)
      iex> a == TartarusEmu.Topology.random_geometric(20, 0.4, 7, connected: true)
      true
      iex> TartarusEmu.Topology.connected?(a)
      true
  """
  @spec random_geometric(pos_integer, number, integer | :rand.state(), keyword) :: t
  def random_geometric(n, radius, seed, opts \\ []) do
    check_count!(:random_geometric, n, 1)

    if not (is_number(radius) and radius >= 0) do
      raise ArgumentError,
            "Topology.random_geometric/4: expected a non-negative radius, got: #{inspect(radius)}"
    end

    rng = if is_integer(seed), do: :rand.seed_s(:exsss, seed), else: seed
    connected = Keyword.get(opts, :connected, false)
    max_attempts = Keyword.get(opts, :max_attempts, 1000)
    draw_geometric(n, radius, rng, connected, max_attempts, 1)
  end

  defp draw_geometric(n, radius, _rng, true, max, attempt) when attempt > max do
    raise ArgumentError,
          "Topology.random_geometric/4: no connected graph of #{n} nodes with radius " <>
            "#{radius} in #{max} attempts; expected a larger radius or more :max_attempts"
  end

  defp draw_geometric(n, radius, rng, connected, max, attempt) do
    names = names(n)

    {points, rng} =
      Enum.map_reduce(names, rng, fn h, rng ->
        {x, rng} = :rand.uniform_s(rng)
        {y, rng} = :rand.uniform_s(rng)
        {{h, {x, y}}, rng}
      end)

    edges =
      for {{a, {xa, ya}}, i} <- Enum.with_index(points),
          {{b, {xb, yb}}, j} <- Enum.with_index(points),
          i < j,
          :math.sqrt((xa - xb) * (xa - xb) + (ya - yb) * (ya - yb)) <= radius,
          do: {a, b}

    topo = new(names, edges, positions: Map.new(points), kind: :random_geometric)

    if connected and not connected?(topo) do
      draw_geometric(n, radius, rng, connected, max, attempt + 1)
    else
      topo
    end
  end

  defp names(n), do: for(i <- 1..n, do: :"h#{i}")

  defp check_count!(builder, n, min) do
    if not (is_integer(n) and n >= min) do
      raise ArgumentError,
            "Topology.#{builder}: expected an integer >= #{min}, got: #{inspect(n)}"
    end
  end

  ## File format

  @doc """
  Reads a floor-plan file (format in the moduledoc). Same options as `parse/2`.
  """
  @spec from_file(Path.t(), keyword) :: {:ok, t} | {:error, String.t()}
  def from_file(path, opts \\ []) do
    case File.read(path) do
      {:ok, text} ->
        case parse(text, opts) do
          {:ok, topo} -> {:ok, topo}
          {:error, reason} -> {:error, "#{path}: #{reason}"}
        end

      {:error, reason} ->
        {:error, "cannot read topology file #{path}: #{:file.format_error(reason)}"}
    end
  end

  @doc """
  Parses the floor-plan text format (see the moduledoc). Node names stay strings unless
  `names: %{"file name" => atom}` maps them.

  ## Examples

      iex> {:ok, topo} = TartarusEmu.Topology.parse(\"""
      ...> node a 0 0   # the door
      ...> node b 1 0 floor 2
      ...> edge a b latency_ms=5
      ...> \""")
      iex> {topo.nodes, topo.floors, TartarusEmu.Topology.fetch_link(topo, "b", "a")}
      {["a", "b"], %{"b" => 2}, {:ok, %{latency_ms: 5, loss: 0.0}}}

      iex> TartarusEmu.Topology.parse("node a\\nedge a z\\n")
      {:error, "line 2: edge to undeclared node \\"z\\""}
  """
  @spec parse(String.t(), keyword) :: {:ok, t} | {:error, String.t()}
  def parse(text, opts \\ []) when is_binary(text) do
    names = Keyword.get(opts, :names)

    if not (names == nil or is_map(names)) do
      raise ArgumentError,
            "Topology.parse/2: expected :names to be a map of strings to atoms, got: #{inspect(names)}"
    end

    acc = %{
      nodes: [],
      seen: %{},
      positions: %{},
      floors: %{},
      zones: %{},
      floor: nil,
      edges: [],
      line: 0
    }

    text
    |> String.split(["\r\n", "\n"])
    |> Enum.with_index(1)
    |> Enum.reduce_while({:ok, acc}, fn {line, no}, {:ok, acc} ->
      case parse_line(tokens(line), %{acc | line: no}, names) do
        {:ok, acc} -> {:cont, {:ok, acc}}
        {:error, msg} -> {:halt, {:error, "line #{no}: #{msg}"}}
      end
    end)
    |> case do
      {:ok, acc} -> build_parsed(acc)
      error -> error
    end
  end

  defp tokens(line) do
    line
    |> String.split("#", parts: 2)
    |> hd()
    |> String.split([" ", "\t"], trim: true)
  end

  defp parse_line([], acc, _names), do: {:ok, acc}

  defp parse_line(["floor", f], acc, _names) do
    with {:ok, floor} <- parse_int(f, "floor") do
      {:ok, %{acc | floor: floor}}
    end
  end

  defp parse_line(["floor" | args], _acc, _names) do
    {:error, "expected \"floor F\" with one integer, got: #{inspect(Enum.join(args, " "))}"}
  end

  defp parse_line(["node", raw | args], acc, names) do
    with {:ok, name} <- node_name(raw, names),
         :ok <- unique_node(name, raw, acc),
         {:ok, pos, floor, zone} <- node_args(args, acc.floor) do
      acc = %{acc | nodes: [name | acc.nodes], seen: Map.put(acc.seen, raw, name)}
      acc = if pos, do: %{acc | positions: Map.put(acc.positions, name, pos)}, else: acc
      acc = if floor, do: %{acc | floors: Map.put(acc.floors, name, floor)}, else: acc
      acc = if zone, do: %{acc | zones: Map.put(acc.zones, name, zone)}, else: acc
      {:ok, acc}
    end
  end

  defp parse_line(["edge", a, b | attrs], acc, _names) do
    cond do
      a == b ->
        {:error, "expected an edge between two different nodes, got a self-loop on #{inspect(a)}"}

      true ->
        with {:ok, attrs} <- edge_attrs(attrs, %{}) do
          # Nodes may be declared later in the file: edges are resolved after the last line.
          {:ok, %{acc | edges: [{a, b, attrs, acc.line} | acc.edges]}}
        end
    end
  end

  defp parse_line([directive | _], _acc, _names) when directive in ["node", "edge"] do
    usage =
      if directive == "node",
        do: "node NAME [X Y [Z]] [floor F] [zone Z]",
        else: "edge A B [attr=value ...]"

    {:error, "expected \"#{usage}\", got too few arguments"}
  end

  defp parse_line([directive | _], _acc, _names) do
    {:error, "unknown directive #{inspect(directive)}: expected \"node\", \"edge\" or \"floor\""}
  end

  defp node_name(raw, names) do
    cond do
      not Regex.match?(~r/\A[A-Za-z0-9_.:\-]{1,64}\z/, raw) ->
        {:error,
         "expected a node name of 1 to 64 characters from A-Z a-z 0-9 _ - . :, got: #{inspect(raw)}"}

      names == nil ->
        {:ok, raw}

      is_map(names) and is_map_key(names, raw) ->
        {:ok, Map.fetch!(names, raw)}

      true ->
        {:error, "node #{inspect(raw)} is not in the :names mapping"}
    end
  end

  defp unique_node(name, raw, acc) do
    if Map.has_key?(acc.seen, raw) or name in acc.nodes,
      do: {:error, "duplicate node #{inspect(raw)}"},
      else: :ok
  end

  # [X Y [Z]] then any of "floor F", "zone Z" (each at most once).
  defp node_args(args, floor) do
    {numbers, rest} = Enum.split_while(args, &(&1 not in ["floor", "zone"]))

    with {:ok, pos} <- node_position(numbers),
         {:ok, attrs} <- node_attrs(rest, %{}) do
      {:ok, pos, Map.get(attrs, "floor", floor), Map.get(attrs, "zone")}
    end
  end

  defp node_position([]), do: {:ok, nil}

  defp node_position([_, _] = xy), do: parse_coords(xy, ["x", "y"])
  defp node_position([_, _, _] = xyz), do: parse_coords(xyz, ["x", "y", "z"])

  defp node_position(args) do
    {:error,
     "expected \"[X Y [Z]] [floor F] [zone Z]\" after the node name, got: #{inspect(Enum.join(args, " "))}"}
  end

  defp parse_coords(texts, axes) do
    texts
    |> Enum.zip(axes)
    |> Enum.reduce_while({:ok, []}, fn {text, axis}, {:ok, acc} ->
      case parse_number(text, "#{axis} coordinate") do
        {:ok, v} -> {:cont, {:ok, [v * 1.0 | acc]}}
        error -> {:halt, error}
      end
    end)
    |> case do
      {:ok, coords} -> {:ok, coords |> Enum.reverse() |> List.to_tuple()}
      error -> error
    end
  end

  defp node_attrs([], acc), do: {:ok, acc}

  defp node_attrs([key, _ | _], acc) when key in ["floor", "zone"] and is_map_key(acc, key),
    do: {:error, "#{key} given twice"}

  defp node_attrs(["floor", f | rest], acc) do
    with {:ok, f} <- parse_int(f, "floor"), do: node_attrs(rest, Map.put(acc, "floor", f))
  end

  defp node_attrs(["zone", z | rest], acc), do: node_attrs(rest, Map.put(acc, "zone", z))

  defp node_attrs(args, _acc) do
    {:error,
     "expected \"[X Y [Z]] [floor F] [zone Z]\" after the node name, got: #{inspect(Enum.join(args, " "))}"}
  end

  defp edge_attrs([], acc), do: {:ok, acc}

  defp edge_attrs([attr | rest], acc) do
    case String.split(attr, "=", parts: 2) do
      [key, _]
      when (key == "latency_ms" and is_map_key(acc, :latency_ms)) or
             (key == "loss" and is_map_key(acc, :loss)) ->
        {:error, "attribute #{key} given twice"}

      ["latency_ms", value] ->
        case parse_number(value, "latency_ms") do
          {:ok, ms} when ms >= 0 -> edge_attrs(rest, Map.put(acc, :latency_ms, ms))
          {:ok, _} -> {:error, "expected latency_ms >= 0, got: #{value}"}
          error -> error
        end

      ["loss", value] ->
        case parse_number(value, "loss") do
          {:ok, p} when p >= 0 and p <= 1 -> edge_attrs(rest, Map.put(acc, :loss, p * 1.0))
          {:ok, _} -> {:error, "expected loss between 0 and 1, got: #{value}"}
          error -> error
        end

      _ ->
        {:error, "unknown edge attribute #{inspect(attr)}: expected latency_ms=N or loss=P"}
    end
  end

  defp parse_int(text, what) do
    case Integer.parse(text) do
      {int, ""} -> {:ok, int}
      _ -> {:error, "expected an integer #{what}, got: #{inspect(text)}"}
    end
  end

  defp parse_number(text, what) do
    case Integer.parse(text) do
      {int, ""} ->
        {:ok, int}

      _ ->
        case Float.parse(text) do
          {float, ""} -> {:ok, float}
          _ -> {:error, "expected a number for #{what}, got: #{inspect(text)}"}
        end
    end
  end

  defp build_parsed(acc) do
    acc.edges
    |> Enum.reverse()
    |> Enum.reduce_while({:ok, MapSet.new(), %{}}, fn {a, b, attrs, no}, {:ok, edges, links} ->
      with {:ok, na} <- resolve(acc.seen, a, no),
           {:ok, nb} <- resolve(acc.seen, b, no),
           edge = norm(na, nb),
           false <- MapSet.member?(edges, edge) do
        links = if attrs == %{}, do: links, else: Map.put(links, edge, attrs)
        {:cont, {:ok, MapSet.put(edges, edge), links}}
      else
        true ->
          {:halt, {:error, "line #{no}: duplicate edge between #{inspect(a)} and #{inspect(b)}"}}

        {:error, _} = error ->
          {:halt, error}
      end
    end)
    |> case do
      {:ok, edges, links} ->
        {:ok,
         %__MODULE__{
           nodes: Enum.reverse(acc.nodes),
           edges: edges,
           positions: acc.positions,
           floors: acc.floors,
           zones: acc.zones,
           links: links,
           kind: :file
         }}

      error ->
        error
    end
  end

  defp resolve(seen, raw, no) do
    case Map.fetch(seen, raw) do
      {:ok, name} -> {:ok, name}
      :error -> {:error, "line #{no}: edge to undeclared node #{inspect(raw)}"}
    end
  end

  @doc """
  Writes `topo` in the file format, so that `parse/2` reads it back (names are written with
  `to_string/1`; positions, floors, zones (as strings) and link attributes are kept;
  `attrs` are not written).

  ## Examples

      iex> TartarusEmu.Topology.line(2) |> TartarusEmu.Topology.to_text()
      "node h1 0.0 0.0\\nnode h2 1.0 0.0\\nedge h1 h2\\n"
  """
  @spec to_text(t) :: String.t()
  def to_text(%__MODULE__{} = topo) do
    node_lines =
      Enum.map(topo.nodes, fn n ->
        pos =
          case Map.fetch(topo.positions, n) do
            {:ok, {x, y}} -> [" ", num(x), " ", num(y)]
            {:ok, {x, y, z}} -> [" ", num(x), " ", num(y), " ", num(z)]
            :error -> []
          end

        zone =
          case Map.fetch(topo.zones, n) do
            {:ok, z} -> [" zone ", to_string(z)]
            :error -> []
          end

        floor =
          case Map.fetch(topo.floors, n) do
            {:ok, f} -> [" floor ", Integer.to_string(f)]
            :error -> []
          end

        ["node ", to_string(n), pos, floor, zone, "\n"]
      end)

    edge_lines =
      topo.edges
      |> Enum.sort()
      |> Enum.map(fn {a, b} = edge ->
        attrs =
          topo.links
          |> Map.get(edge, %{})
          |> Enum.sort()
          |> Enum.map(fn {k, v} -> [" ", Atom.to_string(k), "=", num(v)] end)

        ["edge ", to_string(a), " ", to_string(b), attrs, "\n"]
      end)

    IO.iodata_to_binary([node_lines, edge_lines])
  end

  defp num(x) when is_integer(x), do: Integer.to_string(x)
  defp num(x) when is_float(x), do: Float.to_string(x)
end
