defmodule TartarusLats.Replay.Devices do
  @moduledoc """
  The receivers of a real-data replay and the floor plan LATS runs on.

  ## Devices file

  Either the tetam format (a line `Dongles:{"<receiver>": [[x, y, z], <colour>, "<alias>"],
  ...}`, the other lines ignored), or a CSV, one receiver a line:

      receiver, x, y, z[, name]

  (metres; blank lines, `#` comments and a header whose first field is `receiver` are
  skipped). A receiver's node is named by its alias or `name` (else by its id): the node
  names of the building. `read!/1` returns `%{receiver_id => %{name: atom, pos: {x, y, z}}}`.

  ## The neighbour relation: a Delaunay graph

  A second's true zone is the receiver nearest the true position (in the plane), so the
  zones are the receivers' Voronoi cells, and a beacon that moves from one cell to another
  crosses a boundary between two cells that touch: the Delaunay edges (the dual of the
  Voronoi diagram). So the neighbours of a node are its Delaunay neighbours in the plane
  (`delaunay/1`: every triangle of receivers whose circumcircle holds no other receiver;
  receivers on one circle, up to 1 mm, give both diagonals). Every true zone change is then
  between neighbours, which is what the handshake of the motion vectors needs. Heights (`z`)
  are kept for the record; the graph ignores them.

  ## Floor-plan file

  `write_floor_plan!/2` writes the building LATS runs on, a text file:

      # tartarus-lats floor plan v1
      node sensor10 7.0 7.09 1.22 entrance
      edge sensor10 sensor11

  `node NAME X Y Z [entrance]` and `edge A B`; `read_floor_plan!/1` reads it back into a
  `TartarusLats.Building`. In an open office every zone is an entrance: the tag may be
  first seen anywhere, and a Trace may start in any zone.
  """

  alias TartarusLats.Building

  @typedoc "The receivers: id => name (the node) and position."
  @type t :: %{String.t() => %{name: atom(), pos: {float(), float(), float()}}}

  @doc "Reads a devices file (tetam `.dev` or CSV, see the moduledoc). Raises `ArgumentError` on a malformed file."
  @spec read!(Path.t()) :: t()
  def read!(path), do: path |> File.read!() |> parse!()

  @doc """
  Parses a devices file's text.

      iex> TartarusLats.Replay.Devices.parse!("receiver,x,y,z,name\\naa,0,0,1,left\\nbb,5,0,1")
      %{"aa" => %{name: :left, pos: {0.0, 0.0, 1.0}}, "bb" => %{name: :bb, pos: {5.0, 0.0, 1.0}}}
  """
  @spec parse!(binary()) :: t()
  def parse!(text) do
    case Regex.run(~r/^Dongles:\s*(\{.*\})\s*$/m, text) do
      [_, dict] -> tetam!(dict)
      nil -> csv!(text)
    end
  end

  defp tetam!(dict) do
    case Tartarus.JSON.decode(dict) do
      {:ok, map} when is_map(map) and map_size(map) > 0 ->
        Map.new(map, fn
          {id, [[x, y, z] | rest]} when is_number(x) and is_number(y) and is_number(z) ->
            name = Enum.find(rest, &is_binary/1) || id
            {id, %{name: String.to_atom(name), pos: {x * 1.0, y * 1.0, z * 1.0}}}

          other ->
            raise ArgumentError,
                  "devices: expected \"id\": [[x, y, z], ...], got: #{inspect(other)}"
        end)
        |> check_names!()

      other ->
        raise ArgumentError, "devices: the Dongles line is not a dictionary: #{inspect(other)}"
    end
  end

  defp csv!(text) do
    text
    |> String.split(["\r\n", "\n"])
    |> Enum.with_index(1)
    |> Enum.reject(fn {l, _} ->
      t = String.trim(l)
      t == "" or String.starts_with?(t, "#") or String.starts_with?(t, "receiver")
    end)
    |> Enum.map(fn {line, no} ->
      case line |> String.split(",") |> Enum.map(&String.trim/1) do
        [id, x, y, z | name] when id != "" ->
          with {x, ""} <- Float.parse(x), {y, ""} <- Float.parse(y), {z, ""} <- Float.parse(z) do
            {id, %{name: String.to_atom(List.first(name) || id), pos: {x, y, z}}}
          else
            _ ->
              raise ArgumentError, "devices:#{no}: x, y, z must be numbers, got: #{inspect(line)}"
          end

        _ ->
          raise ArgumentError,
                "devices:#{no}: expected receiver, x, y, z[, name], got: #{inspect(line)}"
      end
    end)
    |> Map.new()
    |> check_names!()
  end

  defp check_names!(devices) do
    names = Enum.map(devices, fn {_, d} -> d.name end)

    cond do
      devices == %{} -> raise ArgumentError, "devices: no receivers"
      length(Enum.uniq(names)) != length(names) -> raise ArgumentError, "devices: names repeat"
      true -> devices
    end
  end

  @doc """
  The Delaunay edges of points in the plane (`%{name => {x, y}}` or `{x, y, z}`, z
  ignored): `[{a, b}]` with `a < b`, sorted. Brute force over the triangles (fine for tens
  of receivers). Points on one circle (up to 1 mm) give every diagonal.

      iex> TartarusLats.Replay.Devices.delaunay(%{a: {0, 0}, b: {4, 0}, c: {0, 3}, d: {9, 9}})
      [{:a, :b}, {:a, :c}, {:b, :c}, {:b, :d}, {:c, :d}]
  """
  @spec delaunay(%{term() => tuple()}) :: [{term(), term()}]
  def delaunay(points) do
    pts = Enum.map(points, fn {n, p} -> {n, {elem(p, 0) * 1.0, elem(p, 1) * 1.0}} end)
    pts = Enum.sort(pts)

    triangles =
      for {a, i} <- Enum.with_index(pts),
          {b, j} <- Enum.with_index(pts),
          j > i,
          {c, k} <- Enum.with_index(pts),
          k > j,
          circle = circumcircle(elem(a, 1), elem(b, 1), elem(c, 1)),
          circle != nil,
          {{cx, cy}, r} = circle,
          Enum.all?(pts, fn {n, {x, y}} ->
            n in [elem(a, 0), elem(b, 0), elem(c, 0)] or
              :math.sqrt((x - cx) ** 2 + (y - cy) ** 2) >= r - 1.0e-3
          end),
          do: [elem(a, 0), elem(b, 0), elem(c, 0)]

    triangles
    |> Enum.flat_map(fn [a, b, c] -> [{a, b}, {a, c}, {b, c}] end)
    |> Enum.map(fn {a, b} -> if a < b, do: {a, b}, else: {b, a} end)
    |> Enum.uniq()
    |> Enum.sort()
  end

  defp circumcircle({ax, ay}, {bx, by}, {cx, cy}) do
    d = 2 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))

    if abs(d) < 1.0e-9 do
      nil
    else
      a2 = ax * ax + ay * ay
      b2 = bx * bx + by * by
      c2 = cx * cx + cy * cy
      ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
      uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
      {{ux, uy}, :math.sqrt((ax - ux) ** 2 + (ay - uy) ** 2)}
    end
  end

  @doc """
  The building LATS runs on for these receivers: one node per receiver (named by it), at
  its position, neighbours by `delaunay/1`, every node an entrance (see the moduledoc).
  """
  @spec building(t()) :: Building.t()
  def building(devices) do
    positions = Map.new(devices, fn {_id, d} -> {d.name, d.pos} end)
    adjacency = Enum.group_by(delaunay(positions), &elem(&1, 0), &elem(&1, 1))

    Building.custom(
      positions: positions,
      adjacency: adjacency,
      entrances: Enum.sort(Map.keys(positions)),
      floor_height: 100.0
    )
  end

  @doc "Writes a building as a floor-plan file (see the moduledoc)."
  @spec write_floor_plan!(Path.t(), Building.t()) :: :ok
  def write_floor_plan!(path, building), do: File.write!(path, floor_plan(building))

  @doc "A building as the text of a floor-plan file."
  @spec floor_plan(Building.t()) :: String.t()
  def floor_plan(building) do
    entrances = Building.entrances(building)
    nodes = Building.nodes(building)

    node_lines =
      for n <- nodes do
        {x, y, z} = Building.position(building, n)
        door = if n in entrances, do: " entrance", else: ""
        "node #{n} #{num(x)} #{num(y)} #{num(z)}#{door}\n"
      end

    edge_lines =
      for n <- nodes, m <- Building.neighbours(building, n), n < m, do: "edge #{n} #{m}\n"

    IO.iodata_to_binary(["# tartarus-lats floor plan v1\n", node_lines, edge_lines])
  end

  defp num(x), do: :erlang.float_to_binary(x * 1.0, [:compact, decimals: 3])

  @doc """
  Reads a floor-plan file into a `TartarusLats.Building`. Raises `ArgumentError` naming the
  line on a malformed one.

      iex> text = "node a 0 0 1 entrance\\nnode b 5 0 1\\nedge a b\\n"
      iex> b = TartarusLats.Replay.Devices.parse_floor_plan!(text)
      iex> {TartarusLats.Building.neighbours(b, :a), TartarusLats.Building.entrances(b)}
      {[:b], [:a]}
  """
  @spec parse_floor_plan!(binary()) :: Building.t()
  def parse_floor_plan!(text) do
    {nodes, edges, doors} =
      text
      |> String.split(["\r\n", "\n"])
      |> Enum.with_index(1)
      |> Enum.reduce({%{}, [], []}, fn {line, no}, {nodes, edges, doors} ->
        case String.split(String.trim(line)) do
          [] ->
            {nodes, edges, doors}

          ["#" <> _ | _] ->
            {nodes, edges, doors}

          ["node", name, x, y, z | door] ->
            n = String.to_atom(name)
            pos = List.to_tuple(Enum.map([x, y, z], &float!(&1, no)))

            {Map.put(nodes, n, pos), edges,
             if(door == ["entrance"], do: [n | doors], else: doors)}

          ["edge", a, b] ->
            {nodes, [{String.to_atom(a), String.to_atom(b)} | edges], doors}

          _ ->
            raise ArgumentError,
                  "floor plan:#{no}: expected node NAME X Y Z [entrance] or edge A B"
        end
      end)

    Building.custom(
      positions: nodes,
      adjacency: Enum.group_by(edges, &elem(&1, 0), &elem(&1, 1)),
      entrances: if(doors == [], do: Enum.sort(Map.keys(nodes)), else: Enum.sort(doors)),
      floor_height: 100.0
    )
  end

  @doc "Reads a floor-plan file (`parse_floor_plan!/1`)."
  @spec read_floor_plan!(Path.t()) :: Building.t()
  def read_floor_plan!(path), do: path |> File.read!() |> parse_floor_plan!()

  defp float!(s, no) do
    case Float.parse(s) do
      {x, ""} -> x
      _ -> raise ArgumentError, "floor plan:#{no}: not a number: #{inspect(s)}"
    end
  end
end
