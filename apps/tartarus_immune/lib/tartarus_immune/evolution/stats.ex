defmodule TartarusImmune.Evolution.Stats do
  @moduledoc """
  The significance test of the embodied-evolution comparisons: a one-sided Mann-Whitney U
  (Wilcoxon rank-sum) test of "the first sample tends to be larger than the second", with
  an **exact** p-value: the permutation distribution of the rank sum, conditional on the
  ties (mid-ranks), counted by dynamic programming over the pooled sample (no normal
  approximation: with 10 trials a side and many tied success rates, the approximation is
  poor). Pure functions.

      iex> alias TartarusImmune.Evolution.Stats
      iex> r = Stats.mann_whitney([0.9, 0.8, 0.7], [0.1, 0.2, 0.3])
      iex> {r.u, Float.round(r.p_value, 4)}
      {9.0, 0.05}
      iex> Stats.mann_whitney([0.1, 0.2, 0.3], [0.9, 0.8, 0.7]).p_value
      1.0
  """

  @typedoc "The test's outcome: U of the first sample, the exact one-sided p-value, sizes."
  @type result :: %{u: float(), p_value: float(), n1: non_neg_integer(), n2: non_neg_integer()}

  @doc """
  One-sided Mann-Whitney U test that `xs` is stochastically larger than `ys`.

  `u` counts the pairs `(x, y)` with `x > y`, ties counting one half (so `u` is
  `n1 * n2` when every x beats every y); `p_value` is the probability, over all ways of
  splitting the pooled values into groups of `n1` and `n2`, of a rank sum of the first
  group at least as large as observed. Identical samples give 1.0 or close to it; empty
  samples give `p_value` 1.0.

      iex> r = TartarusImmune.Evolution.Stats.mann_whitney([1, 1, 0], [0, 0, 0])
      iex> {r.u, Float.round(r.p_value, 3)}
      {7.5, 0.2}
  """
  @spec mann_whitney([number()], [number()]) :: result()
  def mann_whitney(xs, ys) do
    n1 = length(xs)
    n2 = length(ys)

    if n1 == 0 or n2 == 0 do
      %{u: 0.0, p_value: 1.0, n1: n1, n2: n2}
    else
      u =
        Enum.reduce(xs, 0.0, fn x, acc ->
          Enum.reduce(ys, acc, fn
            y, a when x > y -> a + 1.0
            y, a when x == y -> a + 0.5
            _, a -> a
          end)
        end)

      # doubled mid-ranks of the pooled sample: integers
      pooled = Enum.map(xs, &{&1 * 1.0, :x}) ++ Enum.map(ys, &{&1 * 1.0, :y})
      ranks2 = doubled_ranks(pooled)

      observed =
        pooled
        |> Enum.zip(ranks2)
        |> Enum.filter(fn {{_, g}, _} -> g == :x end)
        |> Enum.map(&elem(&1, 1))
        |> Enum.sum()

      counts = rank_sum_counts(ranks2, n1)
      total = counts |> Map.values() |> Enum.sum()
      tail = counts |> Enum.filter(fn {s, _} -> s >= observed end) |> Enum.map(&elem(&1, 1))

      %{u: u, p_value: Enum.sum(tail) / total, n1: n1, n2: n2}
    end
  end

  # 2 x the mid-rank of every value (ranks from 1), in the pooled order.
  defp doubled_ranks(pooled) do
    sorted = pooled |> Enum.map(&elem(&1, 0)) |> Enum.sort()

    first_last =
      sorted
      |> Enum.with_index(1)
      |> Enum.reduce(%{}, fn {v, i}, acc ->
        Map.update(acc, v, {i, i}, fn {a, _} -> {a, i} end)
      end)

    Enum.map(pooled, fn {v, _} ->
      {a, b} = first_last[v]
      a + b
    end)
  end

  # For every attainable sum of k of the (doubled) ranks, in how many ways it is attained.
  defp rank_sum_counts(ranks2, k) do
    init = %{{0, 0} => 1}

    ranks2
    |> Enum.reduce(init, fn r, table ->
      Enum.reduce(table, table, fn {{j, s}, c}, acc ->
        if j < k, do: Map.update(acc, {j + 1, s + r}, c, &(&1 + c)), else: acc
      end)
    end)
    |> Enum.filter(fn {{j, _}, _} -> j == k end)
    |> Map.new(fn {{_, s}, c} -> {s, c} end)
  end
end
