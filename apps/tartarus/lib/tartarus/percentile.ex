defmodule Tartarus.Percentile do
  @moduledoc """
  Percentiles by nearest rank: the value at quantile `q` (0..1) is the `ceil(q * n)`-th
  smallest of `n` samples (at least the first), an actual sample; `nil` for no samples.
  The one definition of the platform's hop statistics, the dashboard's and the tooling.s.

      iex> Tartarus.Percentile.of([5, 1, 4, 2, 3], 0.5)
      3
      iex> Tartarus.Percentile.sorted([1, 2, 3, 4], 0.5)
      2
      iex> Tartarus.Percentile.sorted([1, 2, 3, 4, 100], 0.99)
      100
      iex> Tartarus.Percentile.of([], 0.9)
      nil
  """

  @doc "The value at quantile `q` of `xs` (any order); `nil` for an empty list."
  @spec of([number()], number()) :: number() | nil
  def of(xs, q) when is_list(xs), do: sorted(Enum.sort(xs), q)

  @doc "The value at quantile `q` of `sorted` (ascending); `nil` for an empty list."
  @spec sorted([number()], number()) :: number() | nil
  def sorted([], _q), do: nil

  def sorted(sorted, q) when is_list(sorted) and is_number(q) and q >= 0 and q <= 1 do
    n = length(sorted)
    Enum.at(sorted, min(n - 1, max(0, ceil(q * n) - 1)))
  end
end
