defmodule TartarusEmu.Dynamics do
  @moduledoc """
  The thesis's dynamic network, as a pure random process over discrete ticks.

  Every element (a node, or a link for link-level flapping) is either **up** or **down**.
  On each tick, independently of the others and of the past:

    * an up element **breaks off** with probability `p_break` (a node that breaks off takes
      all its links down with it);
    * a down element **reconnects** with probability `p_heal`.

  The thesis uses one probability `p` for both (`step(state, p, rng)`); pass
  `{p_break, p_heal}` to set them apart. Each element is a two-state Markov chain, so:

    * the long-run fraction of ticks an element is down is `p_break / (p_break + p_heal)`,
      which is **1/2 whatever `p`** when both are equal: `p` sets how often the network
      changes, not how much of it is missing;
    * a down spell lasts `1 / p_heal` ticks on average (geometric), an up spell
      `1 / p_break`.

  All elements start up. Elements are visited in sorted order and each tick draws exactly one
  uniform number per element from the explicit `:rand` state you pass in and get back, so a
  run is reproducible from its seed and never touches the process's global random state.

      iex> state = TartarusEmu.Dynamics.new([:h1, :h2, :h3])
      iex> rng = TartarusEmu.Dynamics.rng(1)
      iex> {events, state, _rng} = TartarusEmu.Dynamics.step(state, 0.5, rng)
      iex> Enum.all?(events, &match?({:down, _}, &1))
      true
      iex> length(events) == length(TartarusEmu.Dynamics.down(state))
      true

  To flap links instead of nodes, track the topology's edges:
  `new(MapSet.to_list(topo.edges))`; `live_edges/3` combines both views.
  """

  defstruct elements: [], down: MapSet.new(), tick: 0

  @typedoc "A tracked element: a node name, or an `{a, b}` edge for link flapping."
  @type element :: term

  @typedoc "An event of one tick."
  @type event :: {:down, element} | {:up, element}

  @typedoc "A probability per tick, or `{p_break, p_heal}`."
  @type probability :: number | {number, number}

  @type t :: %__MODULE__{elements: [element], down: MapSet.t(element), tick: non_neg_integer}

  @doc """
  A state tracking `elements`, all up, at tick 0.

  ## Examples

      iex> TartarusEmu.Dynamics.new([:b, :a]).elements
      [:a, :b]
  """
  @spec new([element]) :: t
  def new(elements) when is_list(elements) do
    %__MODULE__{elements: elements |> Enum.uniq() |> Enum.sort()}
  end

  @doc """
  An explicit `:exsss` random state from an integer seed.

  ## Examples

      iex> TartarusEmu.Dynamics.rng(3) == TartarusEmu.Dynamics.rng(3)
      true
  """
  @spec rng(integer) :: :rand.state()
  def rng(seed) when is_integer(seed), do: :rand.seed_s(:exsss, seed)

  @doc """
  Advances one tick. Returns the events of this tick (in element order), the new state and
  the new random state.

  ## Examples

      iex> state = TartarusEmu.Dynamics.new([:a, :b])
      iex> {events, state, _} = TartarusEmu.Dynamics.step(state, 1.0, TartarusEmu.Dynamics.rng(1))
      iex> {events, state.tick}
      {[down: :a, down: :b], 1}
      iex> {events, _, _} = TartarusEmu.Dynamics.step(state, {0.0, 1.0}, TartarusEmu.Dynamics.rng(1))
      iex> events
      [up: :a, up: :b]
  """
  @spec step(t, probability, :rand.state()) :: {[event], t, :rand.state()}
  def step(%__MODULE__{} = state, p, rng) do
    {p_break, p_heal} = probabilities!(p)

    {events, rng} =
      Enum.flat_map_reduce(state.elements, rng, fn el, rng ->
        {u, rng} = :rand.uniform_s(rng)

        if MapSet.member?(state.down, el) do
          if u < p_heal, do: {[{:up, el}], rng}, else: {[], rng}
        else
          if u < p_break, do: {[{:down, el}], rng}, else: {[], rng}
        end
      end)

    down =
      Enum.reduce(events, state.down, fn
        {:down, el}, acc -> MapSet.put(acc, el)
        {:up, el}, acc -> MapSet.delete(acc, el)
      end)

    {events, %{state | down: down, tick: state.tick + 1}, rng}
  end

  @doc """
  Runs `ticks` steps, returning all events tagged with their tick (1-based), the final state
  and random state.

  ## Examples

      iex> {events, state, _} =
      ...>   TartarusEmu.Dynamics.run(TartarusEmu.Dynamics.new([:a]), 0.0, 5, TartarusEmu.Dynamics.rng(1))
      iex> {events, state.tick}
      {[], 5}
  """
  @spec run(t, probability, non_neg_integer, :rand.state()) ::
          {[{pos_integer, event}], t, :rand.state()}
  def run(%__MODULE__{} = state, p, ticks, rng) when is_integer(ticks) and ticks >= 0 do
    {events, {state, rng}} =
      Enum.flat_map_reduce(List.duplicate(:tick, ticks), {state, rng}, fn :tick, {state, rng} ->
        {events, state, rng} = step(state, p, rng)
        {Enum.map(events, &{state.tick, &1}), {state, rng}}
      end)

    {events, state, rng}
  end

  @doc """
  True when `element` is up (untracked elements count as up).

  ## Examples

      iex> TartarusEmu.Dynamics.new([:a]) |> TartarusEmu.Dynamics.up?(:a)
      true
  """
  @spec up?(t, element) :: boolean
  def up?(%__MODULE__{down: down}, element), do: not MapSet.member?(down, element)

  @doc """
  The elements currently down, sorted.

  ## Examples

      iex> TartarusEmu.Dynamics.new([:a]) |> TartarusEmu.Dynamics.down()
      []
  """
  @spec down(t) :: [element]
  def down(%__MODULE__{down: down}), do: down |> MapSet.to_list() |> Enum.sort()

  @doc """
  The edges usable now: both end nodes up in `node_state` and, when a `link_state` tracking
  edges is given, the edge itself up.

  ## Examples

      iex> edges = MapSet.new([{:a, :b}, {:b, :c}])
      iex> {_, nodes, _} =
      ...>   TartarusEmu.Dynamics.step(TartarusEmu.Dynamics.new([:c]), 1.0, TartarusEmu.Dynamics.rng(1))
      iex> TartarusEmu.Dynamics.live_edges(edges, nodes)
      MapSet.new([{:a, :b}])
  """
  @spec live_edges(Enumerable.t(), t, t | nil) :: MapSet.t()
  def live_edges(edges, %__MODULE__{} = node_state, link_state \\ nil) do
    edges
    |> Enum.filter(fn {a, b} = edge ->
      up?(node_state, a) and up?(node_state, b) and
        (link_state == nil or up?(link_state, edge))
    end)
    |> MapSet.new()
  end

  defp probabilities!({p_break, p_heal}) do
    {probability!(p_break, "p_break"), probability!(p_heal, "p_heal")}
  end

  defp probabilities!(p), do: {probability!(p, "p"), probability!(p, "p")}

  defp probability!(p, _what) when is_number(p) and p >= 0 and p <= 1, do: p

  defp probability!(p, what) do
    raise ArgumentError,
          "Dynamics.step/3: expected #{what} to be a number between 0 and 1, got: #{inspect(p)}"
  end
end
