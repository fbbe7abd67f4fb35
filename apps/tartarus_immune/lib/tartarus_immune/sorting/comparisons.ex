defmodule TartarusImmune.Sorting.Comparisons do
  @moduledoc """
  The sorting domain (`TartarusImmune.Sorting`) with another cost convention: a solution's
  cost is its **key comparisons alone** (moves not counted). Everything else (features,
  solutions, data sets, the score scale log2(L!)) is `TartarusImmune.Sorting`'s.

  A labelled sensitivity option (`mix tartarus.select --cost comparisons`), not a default:
  under comparisons + moves P1 is a near-tie between insertion and selection sort (47.3
  against 49.0, a swap counting 3 moves); on comparisons alone insertion sort needs about
  19 against selection sort's 28, as the thesis's Fig. 6.3a suggests (docs/immune.md).

      iex> TartarusImmune.Sorting.Comparisons.score(TartarusImmune.Sorting.Insertion, [3, 1, 2])
      3
      iex> TartarusImmune.Sorting.Comparisons.name()
      "sorting (comparisons)"
  """
  @behaviour TartarusImmune.Domain

  alias TartarusImmune.Sorting

  @impl true
  def name, do: "sorting (comparisons)"

  @impl true
  def feature_count, do: Sorting.feature_count()

  @impl true
  def features(instance), do: Sorting.features(instance)

  @impl true
  def solutions, do: Sorting.solutions()

  @impl true
  def solution_name(mod), do: Sorting.solution_name(mod)

  @impl true
  @doc "Key comparisons of a real run of `solution` on `instance` (`Sorting.score/3`)."
  def score(solution, instance), do: Sorting.score(solution, instance, measure: :comparisons)

  @impl true
  def score_scale(instance), do: Sorting.score_scale(instance)

  @impl true
  def sets, do: Sorting.sets()

  @impl true
  def instance(set, i, seed), do: Sorting.instance(set, i, seed)
end
