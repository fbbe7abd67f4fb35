defmodule TartarusRoadblock.Site do
  @moduledoc """
  Where the roadblock scenario happens: the 13-node network and the arena with its layout
  (a module of its own so that the scenario and the administrator's API both use it).
  """

  alias TartarusArena.World

  @line_y 0.8

  @doc """
  The network: 12 computers `pc1..pc12` in a ring and the Pi `pi` beside the path, linked
  to `pc2` and `pc3`. Santa talks to `pc1`, the administrator sits at `pc7`, Rudolph and
  Claus talk to `pc10` and `pc11`.

      iex> t = TartarusRoadblock.Site.topology()
      iex> {TartarusEmu.Topology.size(t), TartarusEmu.Topology.edge_count(t)}
      {13, 14}
  """
  @spec topology() :: TartarusEmu.Topology.t()
  def topology do
    pcs = for i <- 1..12, do: :"pc#{i}"
    ring = Enum.zip(pcs, tl(pcs) ++ [hd(pcs)])
    TartarusEmu.Topology.new(pcs ++ [:pi], ring ++ [{:pi, :pc2}, {:pi, :pc3}])
  end

  @doc """
  The arena of the scenario for a seed, and its layout: a 3 m x 3 m floor with the black
  path along y = #{@line_y} from A (x = 0.35) to B (x = 2.45, marker), Santa at A heading
  to B, the dock (top right) with Claus (claws) and Rudolph (pusher), and where the block
  will appear (x drawn from the seed in 1.2..1.6 m) and the webcam stands.

      iex> {w, layout} = TartarusRoadblock.Site.world(1)
      iex> {Map.keys(w.robots), layout.dest_x}
      {[:claus, :rudolph, :santa], 2.45}
  """
  @spec world(integer()) :: {World.t(), map()}
  def world(seed) do
    {u, _} = :rand.uniform_s(:rand.seed_s(:exsss, {seed, 16, 2004}))
    bx = 1.2 + 0.4 * u
    docks = %{claus: {2.0, 2.3, -:math.pi() / 2}, rudolph: {2.5, 2.3, -:math.pi() / 2}}

    w =
      World.new(seed: seed)
      |> World.add_line([{0.15, @line_y}, {2.85, @line_y}])
      |> World.add_marker(x: 0.35, y: @line_y - 0.12, w: 0.1, h: 0.08, colour: 1, label: "A")
      |> World.add_marker(x: 2.45, y: @line_y - 0.12, w: 0.1, h: 0.08, colour: 4, label: "B")
      |> World.add_marker(x: 2.25, y: 2.3, w: 0.8, h: 0.25, colour: 8, label: "dock")
      |> World.add_robot(:santa, x: 0.35, y: @line_y, theta: 0.0)
      |> add_docked(:claus, docks.claus, :claws)
      |> add_docked(:rudolph, docks.rudolph, :pusher)

    {w,
     %{
       block: {bx, @line_y},
       dest_x: 2.45,
       docks: docks,
       camera: {1.4, 0.25, :math.pi() / 2}
     }}
  end

  defp add_docked(w, id, {x, y, th}, tool),
    do: World.add_robot(w, id, x: x, y: y, theta: th, tool: tool)
end
