defmodule Tartarus.Random do
  @moduledoc """
  Deterministic random streams: the random stream an agent carries with it.

  Every agent has a stream in its envelope (`:rng`, an exported `:rand` state of the
  `:exsss` algorithm). It is seeded when the agent is created, from the `seed:` option of
  `Tartarus.create_agent/4` (for a scenario: derive it from the scenario's seed, e.g.
  `seed: {scenario_seed, i}`; without the option the agent's random id seeds it). The stream
  travels with the agent and only the agent advances it: its own draws (`Tartarus.Agent.uniform/0`
  and friends, inside callbacks) and its own random choices (strategies such as `:random`,
  link loss). So for one seed an agent draws the same numbers wherever it goes, whatever
  the host, node or scheduling.

  A clone's stream is derived from its parent's stream with `fork/1`: the parent draws a
  number, the clone's stream is seeded from it, and the parent goes on from the advanced
  state. Clones are thus reproducible too (they do not depend on the clone's random id),
  and successive clones of one parent get different streams. An agent restarted after a
  crash starts again from its arrival snapshot: it draws the same numbers again.

  This module is pure: each function takes a stream (exported state) and returns the
  value and the advanced stream.

      iex> s = Tartarus.Random.new(42)
      iex> {x, s2} = Tartarus.Random.uniform(s)
      iex> x >= 0.0 and x < 1.0
      true
      iex> {^x, _} = Tartarus.Random.uniform(Tartarus.Random.new(42))
      iex> s2 != s
      true
  """

  # 2^56
  @seed_range 72_057_594_037_927_936

  @typedoc "A random stream: an exported `:rand` state (plain data, it can travel)."
  @type t :: :rand.export_state()

  @doc """
  A stream seeded from `seed` (any term: the same term gives the same stream).

      iex> Tartarus.Random.new({7, 1}) == Tartarus.Random.new({7, 1})
      true
      iex> Tartarus.Random.new({7, 1}) == Tartarus.Random.new({7, 2})
      false
  """
  @spec new(term()) :: t()
  def new(seed), do: Tartarus.Envelope.seed_rng(seed)

  @doc """
  A float uniformly distributed in `[0.0, 1.0)`, and the advanced stream.

      iex> {x, _} = Tartarus.Random.uniform(Tartarus.Random.new(1))
      iex> is_float(x)
      true
  """
  @spec uniform(t()) :: {float(), t()}
  def uniform(s), do: with_state(s, &:rand.uniform_s/1)

  @doc """
  An integer uniformly distributed in `1..n`, and the advanced stream.

      iex> {draws, _} = Enum.map_reduce(1..100, Tartarus.Random.new(1), fn _, s -> Tartarus.Random.uniform(s, 6) end)
      iex> Enum.all?(draws, &(&1 in 1..6))
      true
  """
  @spec uniform(t(), pos_integer()) :: {pos_integer(), t()}
  def uniform(s, n) when is_integer(n) and n > 0, do: with_state(s, &:rand.uniform_s(n, &1))

  @doc """
  A float from the standard normal distribution N(0, 1), and the advanced stream.

      iex> {x, _} = Tartarus.Random.normal(Tartarus.Random.new(1))
      iex> is_float(x)
      true
  """
  @spec normal(t()) :: {float(), t()}
  def normal(s), do: with_state(s, &:rand.normal_s/1)

  @doc """
  A float from N(`mean`, `sd`²) (`sd` is the standard deviation), and the advanced stream.

      iex> {x, _} = Tartarus.Random.normal(Tartarus.Random.new(1), 10.0, 0.0)
      iex> x
      10.0
  """
  @spec normal(t(), number(), number()) :: {float(), t()}
  def normal(s, mean, sd) when is_number(mean) and is_number(sd) and sd >= 0 do
    {x, s} = normal(s)
    {mean + sd * x, s}
  end

  @doc """
  The elements of `enumerable` in a random order (Fisher-Yates on the stream), and the
  advanced stream.

      iex> {l, _} = Tartarus.Random.shuffle(Tartarus.Random.new(3), [1, 2, 3, 4, 5])
      iex> Enum.sort(l)
      [1, 2, 3, 4, 5]
  """
  @spec shuffle(t(), Enumerable.t()) :: {list(), t()}
  def shuffle(s, enumerable) do
    tuple = enumerable |> Enum.to_list() |> List.to_tuple()
    n = tuple_size(tuple)
    state = :rand.seed_s(s)

    {tuple, state} =
      if n < 2 do
        {tuple, state}
      else
        Enum.reduce(n..2//-1, {tuple, state}, fn i, {t, st} ->
          {j, st} = :rand.uniform_s(i, st)
          a = elem(t, i - 1)
          b = elem(t, j - 1)
          {t |> put_elem(i - 1, b) |> put_elem(j - 1, a), st}
        end)
      end

    {Tuple.to_list(tuple), :rand.export_seed_s(state)}
  end

  @doc """
  Draws an integer seed (in `1..2^56`) to seed another computation's generator, e.g.
  `:rand.seed_s(:exsss, seed)` or `new/1` for pure batch functions that take a `:rand`
  state; and the advanced stream.

      iex> {seed, _} = Tartarus.Random.seed(Tartarus.Random.new(5))
      iex> is_integer(seed) and seed > 0
      true
  """
  @spec seed(t()) :: {pos_integer(), t()}
  def seed(s), do: uniform(s, @seed_range)

  @doc """
  Splits a stream in two: `{child, parent}`. The parent is the stream advanced by one draw;
  the child is a fresh stream seeded from that draw (used for clones, see the moduledoc).
  Deterministic: the same stream always forks the same way.

      iex> s = Tartarus.Random.new(9)
      iex> {c1, p1} = Tartarus.Random.fork(s)
      iex> {c2, _p2} = Tartarus.Random.fork(p1)
      iex> Tartarus.Random.fork(s) == {c1, p1}
      true
      iex> c1 != c2 and c1 != p1
      true
  """
  @spec fork(t()) :: {t(), t()}
  def fork(s) do
    {x, parent} = seed(s)
    {new({:fork, x}), parent}
  end

  @doc """
  Runs `fun` on the `:rand` state of the stream (`fun.(state)` returns `{value, state}`,
  like the `:rand.*_s` functions), returning the value and the advanced stream.

      iex> {x, _} = Tartarus.Random.with_state(Tartarus.Random.new(1), &:rand.uniform_s(10, &1))
      iex> x in 1..10
      true
  """
  @spec with_state(t(), (:rand.state() -> {value, :rand.state()})) :: {value, t()}
        when value: term()
  def with_state(s, fun) do
    {value, state} = fun.(:rand.seed_s(s))
    {value, :rand.export_seed_s(state)}
  end
end
