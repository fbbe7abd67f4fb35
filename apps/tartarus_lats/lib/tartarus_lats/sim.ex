defmodule TartarusLats.Sim do
  @moduledoc """
  A whole LATS deployment as one pure value: the `TartarusLats.World`, and on
  every node a `TartarusLats.Tracker`, a `TartarusLats.MotionVectors` table
  and the node's log of records. No processes, no platform: messages between
  neighbours are delivered instantly within the same second.

  It is the reference the agent-based deployment is checked against (same
  seed, same world) and the quickest way to get realistic motion-vector
  tables for testing query logic:

      iex> sim = TartarusLats.Sim.new(seed: 1) |> TartarusLats.Sim.run(120)
      iex> sim.world.time
      120
      iex> tag = TartarusLats.World.tag(sim.world, :janitor)
      iex> {:ok, trace} = TartarusLats.MotionVectors.trace(sim.tables, :p3, tag)
      iex> hd(trace.path).node
      :p3

  Each second `step/1` does, in order:

    1. `TartarusLats.World.step/2` (bearers move);
    2. `TartarusLats.World.readings/2` (every node hears every tag or not);
    3. on every node `TartarusLats.Tracker.tick/3`; records are appended to
       the node's log;
    4. every node's report (`TartarusLats.Zone.report/2`) goes to its
       neighbours and every node decides its zone (`TartarusLats.Zone.decide/4`);
       in node order, the `:entered_zone` / `:left_zone` decisions go to the
       node's motion-vector table and the resulting handshake messages are
       delivered to the neighbours (recursively) at once;
    5. `:tick` on every motion-vector table (timeouts);
    6. statistics of detection against ground truth (`stats/1`).
  """

  alias TartarusLats.{Building, MotionVectors, Radio, Region, Tracker, World, Zone}

  defstruct world: nil,
            rng: nil,
            trackers: %{},
            zones: %{},
            tables: %{},
            logs: %{},
            stats: %{seconds: 0, argmax_hits: 0, own_hits: 0, others: 0, others_present: 0}

  @type t :: %__MODULE__{
          world: World.t(),
          rng: Radio.rng(),
          trackers: %{Building.node_name() => Tracker.t()},
          zones: %{Building.node_name() => Zone.t()},
          tables: %{Building.node_name() => MotionVectors.t()},
          logs: %{Building.node_name() => [Tracker.record()]},
          stats: map()
        }

  @doc """
  A new deployment. Options: `:seed` (integer, default 0), `:world` (a
  `TartarusLats.World`, default `TartarusLats.World.new/0`), `:tracker`
  (options for `TartarusLats.Tracker.new/1`; the default calibration uses
  the world's radio exponent and the bearers' Tx power), `:zone` (options
  for `TartarusLats.Zone.new/1`; not `one_holder: true`, whose messages this
  value does not deliver: `TartarusLats.Zone.Net` and `TartarusLats.Deployment` do),
  `:timeout` (handshake timeout, seconds, default 15).

      iex> TartarusLats.Sim.new(zone: [one_holder: true])
      ** (ArgumentError) TartarusLats.Sim does not run the one-holder protocol (zone option one_holder: true); use TartarusLats.Deployment or TartarusLats.Zone.Net
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    if Keyword.get(Keyword.get(opts, :zone, []), :one_holder),
      do:
        raise(
          ArgumentError,
          "TartarusLats.Sim does not run the one-holder protocol (zone option one_holder: true); use TartarusLats.Deployment or TartarusLats.Zone.Net"
        )

    world = Keyword.get_lazy(opts, :world, &World.new/0)
    seed = Keyword.get(opts, :seed, 0)
    cal = Region.calibrate(tx_power: -59, exponent: world.radio.exponent)
    tracker_opts = Keyword.merge([calibration: cal], Keyword.get(opts, :tracker, []))
    timeout = Keyword.get(opts, :timeout, 15)
    nodes = Building.nodes(world.building)

    %__MODULE__{
      world: world,
      rng: Radio.seed(seed),
      trackers: Map.new(nodes, &{&1, Tracker.new(tracker_opts)}),
      zones: Map.new(nodes, &{&1, Zone.new([calibration: cal] ++ Keyword.get(opts, :zone, []))}),
      tables: Map.new(nodes, &{&1, MotionVectors.new(&1, timeout: timeout)}),
      logs: Map.new(nodes, &{&1, []})
    }
  end

  @doc "Runs `seconds` steps."
  @spec run(t(), non_neg_integer()) :: t()
  def run(%__MODULE__{} = sim, seconds),
    do: Enum.reduce(1..seconds//1, sim, fn _, s -> step(s) end)

  @doc """
  Advances the deployment by one second (see the moduledoc).

  `interfere`, if given, is applied to the second's readings before the nodes hear them:
  `interfere.(t, readings)` gets `%{node => %{tag => rssi | :missing}}` and returns the
  readings the receivers report (interference, a faulty receiver, a burst of reflections).
  The world (the ground truth) is not changed.
  """
  @spec step(t(), (integer(), map() -> map()) | nil) :: t()
  def step(%__MODULE__{} = sim, interfere \\ nil) do
    {world, rng} = World.step(sim.world, sim.rng)
    {readings, rng} = World.readings(world, rng)
    now = world.time
    readings = if interfere, do: interfere.(now, readings), else: readings
    sim = %{sim | world: world, rng: rng}

    nodes = Building.nodes(world.building)

    # Every node's tracker takes its readings and logs its records.
    sim =
      Enum.reduce(nodes, sim, fn node, sim ->
        {events, tracker} =
          Tracker.tick(Map.fetch!(sim.trackers, node), now, Map.fetch!(readings, node))

        records = for {:record, record} <- events, do: record

        %{
          sim
          | trackers: Map.put(sim.trackers, node, tracker),
            logs: Map.update!(sim.logs, node, &(Enum.reverse(records) ++ &1))
        }
      end)

    # Every node reports to its neighbours, then every node decides its zone on the same
    # reports (TartarusLats.Zone), and the decisions go to the motion vectors.
    reports = Map.new(nodes, &{&1, Zone.report(sim.zones[&1], sim.trackers[&1])})

    sim =
      Enum.reduce(nodes, sim, fn node, sim ->
        heard = Map.new(Building.neighbours(world.building, node), &{&1, reports[&1]})
        {events, zone} = Zone.decide(sim.zones[node], now, sim.trackers[node], heard)
        sim = %{sim | zones: Map.put(sim.zones, node, zone)}
        Enum.reduce(events, sim, fn event, sim -> deliver(sim, [{node, event}]) end)
      end)

    tables =
      Map.new(sim.tables, fn {node, mv} ->
        {node, elem(MotionVectors.handle(mv, now, :tick), 0)}
      end)

    update_stats(%{sim | tables: tables})
  end

  defp deliver(sim, []), do: sim

  defp deliver(sim, [{node, event} | queue]) do
    {mv, actions} = MotionVectors.handle(Map.fetch!(sim.tables, node), sim.world.time, event)
    sim = %{sim | tables: Map.put(sim.tables, node, mv)}

    out =
      Enum.flat_map(actions, fn
        {:broadcast, msg} -> for n <- Building.neighbours(sim.world.building, node), do: {n, msg}
        {:send, to, msg} -> [{to, msg}]
      end)

    deliver(sim, queue ++ out)
  end

  @doc """
  A node's log of records, oldest first (what its durable store would hold).
  """
  @spec log(t(), Building.node_name()) :: [Tracker.record()]
  def log(%__MODULE__{logs: logs}, node), do: logs |> Map.fetch!(node) |> Enum.reverse()

  @doc """
  Detection quality so far, over the bearer-seconds with a bearer inside:

    * `argmax` - share where the node with the highest filtered RSSI is the
      ground-truth zone;
    * `own_zone` - share where the ground-truth node's tracker says near or far;
    * `false_presence` - share of (other node, bearer-second) pairs where
      another node's tracker says near or far;
    * `records` - total records written.
  """
  @spec stats(t()) :: %{
          seconds: non_neg_integer(),
          argmax: float(),
          own_zone: float(),
          false_presence: float(),
          records: non_neg_integer()
        }
  def stats(%__MODULE__{stats: s, logs: logs}) do
    ratio = fn a, b -> if b == 0, do: 0.0, else: a / b end

    %{
      seconds: s.seconds,
      argmax: ratio.(s.argmax_hits, s.seconds),
      own_zone: ratio.(s.own_hits, s.seconds),
      false_presence: ratio.(s.others_present, s.others),
      records: logs |> Map.values() |> Enum.map(&length/1) |> Enum.sum()
    }
  end

  defp update_stats(sim) do
    world = sim.world
    nodes = Building.nodes(world.building)

    stats =
      Enum.reduce(World.names(world), sim.stats, fn name, s ->
        case World.current_zone(world, name) do
          :outside ->
            s

          zone ->
            tag = World.tag(world, name)
            tracker = Map.fetch!(sim.trackers, zone)

            best =
              nodes
              |> Enum.map(&{&1, Tracker.average(Map.fetch!(sim.trackers, &1), tag)})
              |> Enum.reject(&is_nil(elem(&1, 1)))
              |> Enum.max_by(&elem(&1, 1), fn -> {nil, nil} end)
              |> elem(0)

            present_elsewhere =
              Enum.count(
                nodes,
                &(&1 != zone and Tracker.region(Map.fetch!(sim.trackers, &1), tag) != :beyond)
              )

            %{
              s
              | seconds: s.seconds + 1,
                argmax_hits: s.argmax_hits + if(best == zone, do: 1, else: 0),
                own_hits:
                  s.own_hits + if(Tracker.region(tracker, tag) != :beyond, do: 1, else: 0),
                others: s.others + length(nodes) - 1,
                others_present: s.others_present + present_elsewhere
            }
        end
      end)

    %{sim | stats: stats}
  end
end
