defmodule TartarusLats.Zone.Net do
  @moduledoc """
  The zone decisions of a whole set of nodes as one pure value, with the one-holder
  protocol's messages delivered the way `TartarusLats.Deployment` delivers them between
  database agents: every second each node's tracker takes its samples, every node's
  report (`TartarusLats.Zone.report/2`, when it has one) goes to its neighbours, every node
  decides (`TartarusLats.Zone.decide/4`), then the protocol's messages are delivered in
  rounds (a message sent in round `j` is applied in round `j + 1`, every node's messages of
  a round at once, sorted) until none is left, and every node closes the second
  (`TartarusLats.Zone.close/2`). No motion vectors, no hosts: the reference the property
  test of the protocol runs on, and a quick way to see who holds a tag.

      iex> graph = %{a: [:b], b: [:a, :c], c: [:b]}
      iex> net = TartarusLats.Zone.Net.new(graph, zone: [min_heard: 1, claim_dwell: 1], tracker: [window: 1, median: 1, confirm: 1])
      iex> tag = {"00000000000000000000000000000001", 0, 0}
      iex> {net, _} = TartarusLats.Zone.Net.step(net, 1, %{a: %{tag => -60}})
      iex> TartarusLats.Zone.Net.holders(net, tag)
      [:a]
  """

  alias TartarusLats.{Tracker, Zone}

  defstruct graph: %{}, nodes: %{}, rounds: 0

  @typedoc "Per node its tracker and zone decision; the graph of neighbours."
  @type t :: %__MODULE__{
          graph: %{term() => [term()]},
          nodes: %{term() => {Tracker.t(), Zone.t()}},
          rounds: non_neg_integer()
        }

  @doc """
  A net of the nodes of `graph` (`%{node => [neighbour]}`, symmetric). Options: `:zone`
  (options of `TartarusLats.Zone.new/1`; `:node` and `:neighbours` are set here),
  `:tracker` (of `TartarusLats.Tracker.new/1`) and `:one_holder` (default true; false: the
  zone rule without the protocol, every node deciding on its neighbours' reports alone).
  """
  @spec new(map(), keyword()) :: t()
  def new(graph, opts \\ []) do
    zone = Keyword.get(opts, :zone, []) |> Keyword.drop([:one_holder])
    tracker = Keyword.get(opts, :tracker, [])
    one_holder = Keyword.get(opts, :one_holder, true)

    nodes =
      Map.new(graph, fn {node, ns} ->
        {node,
         {Tracker.new(tracker),
          Zone.new(zone ++ [one_holder: one_holder, node: node, neighbours: ns])}}
      end)

    %__MODULE__{graph: graph, nodes: nodes}
  end

  @doc """
  Second `t`: `readings` is `%{node => %{tag => rssi}}` (a node absent or a tag absent: not
  heard). Returns the net and the zone events of the second, `[{node, event}]` in the
  order they happened.
  """
  @spec step(t(), number(), map()) :: {t(), [{term(), Zone.event()}]}
  def step(%__MODULE__{} = net, t, readings) do
    nodes =
      Map.new(net.nodes, fn {n, {tracker, zone}} ->
        {_events, tracker} = Tracker.tick(tracker, t, Map.get(readings, n, %{}))
        {n, {tracker, zone}}
      end)

    reports =
      for {n, {tracker, zone}} <- nodes,
          r = Zone.report(zone, tracker),
          r != %{},
          into: %{},
          do: {n, r}

    {nodes, events, out} =
      Enum.reduce(Enum.sort(nodes), {nodes, [], []}, fn {n, {tracker, zone}}, {nodes, ev, out} ->
        heard = Map.take(reports, net.graph[n])
        {e, zone} = Zone.decide(zone, t, tracker, heard)
        {msgs, zone} = Zone.take_out(zone)

        {Map.put(nodes, n, {tracker, zone}), ev ++ Enum.map(e, &{n, &1}),
         out ++ Enum.map(msgs, fn {to, m} -> {to, m} end)}
      end)

    {nodes, events, rounds} = rounds(nodes, t, out, events, 0)

    {nodes, events} =
      Enum.reduce(Enum.sort(nodes), {nodes, events}, fn {n, {tracker, zone}}, {nodes, ev} ->
        {e, zone} = Zone.close(zone, t)
        {Map.put(nodes, n, {tracker, zone}), ev ++ Enum.map(e, &{n, &1})}
      end)

    {%{net | nodes: nodes, rounds: max(net.rounds, rounds)}, events}
  end

  defp rounds(nodes, _t, [], events, j), do: {nodes, events, j}

  defp rounds(nodes, t, out, events, j) do
    inbox = Enum.group_by(out, &elem(&1, 0), &elem(&1, 1))

    {nodes, events, out} =
      Enum.reduce(Enum.sort(inbox), {nodes, events, []}, fn {n, msgs}, {nodes, ev, out} ->
        case nodes do
          %{^n => {tracker, zone}} ->
            {e, zone} = Zone.deliver(zone, t, msgs)
            {msgs, zone} = Zone.take_out(zone)
            {Map.put(nodes, n, {tracker, zone}), ev ++ Enum.map(e, &{n, &1}), out ++ msgs}

          _ ->
            {nodes, ev, out}
        end
      end)

    rounds(nodes, t, out, events, j + 1)
  end

  @doc "The nodes that hold `tag` now, sorted."
  @spec holders(t(), term()) :: [term()]
  def holders(%__MODULE__{nodes: nodes}, tag),
    do: for({n, {_tr, z}} <- Enum.sort(nodes), Zone.holds?(z, tag), do: n)
end
