defmodule TartarusImmune.Select.Fig64b do
  @moduledoc """
  Thesis Fig. 6.4b, pre-registered (docs/immune.md, "Fig. 6.4b, the secondary response and
  l_span, pre-registered", dated 2026-12-06): solutions added on the fly on P4.
  `TartarusImmune.Select` runs it (`mix tartarus.select --experiment fig6_4b`).

  The configuration (`config/0`) is the `otfp` experiment's (Fig. 6.4a's) on P4: a 10-host
  grid, β 5, η 0.5, a barrage every 10 rounds; Shell and Selection at the start, Quick,
  Insertion, Merge and Heap added (one iPkt on every host) at rounds 40, 80, 120 and 160;
  300 rounds, not stopped at convergence. The thesis: "for set P4 both Quick and Shell sort
  emerged to be the best solution". The verdict (`verdict/1`) asks whether both hold a
  large share of the live iPkts at the end.
  """

  alias TartarusTools.Stats

  @seeds 2001..2020

  @config [
    set: :p4,
    nodes: 10,
    topology: :grid,
    eta: 0.5,
    beta: 5,
    period: 10,
    steps: 300,
    add_at: [40, 80, 120, 160]
  ]

  @doc """
  The pre-registered configuration.

      iex> TartarusImmune.Select.Fig64b.config()[:add_at]
      [40, 80, 120, 160]
  """
  @spec config() :: keyword()
  def config, do: @config

  @doc "The pre-registered seeds: 2001-2020 (never used before)."
  @spec seeds() :: Range.t()
  def seeds, do: @seeds

  @doc """
  The share of the live iPkts each solution holds in `population` (a map name -> count).

      iex> TartarusImmune.Select.Fig64b.shares(%{"QS" => 30, "ShS" => 10, "IS" => 0})
      %{"IS" => 0.0, "QS" => 0.75, "ShS" => 0.25}
  """
  @spec shares(%{String.t() => non_neg_integer()}) :: %{String.t() => float()}
  def shares(population) do
    total = population |> Map.values() |> Enum.sum()
    Map.new(population, fn {s, n} -> {s, if(total == 0, do: 0.0, else: n / total)} end)
  end

  @doc """
  The verdict, as pre-registered. `finals` are the final populations of the runs (one map
  per seed). A run **has both** when Quick (`"QS"`) and Shell (`"ShS"`) each hold at least
  `min_share` (0.25) of its live iPkts at the end. The outcome is `"reproduced"` when at
  least half of the runs have both, else `"differs"`. Also returned: the runs with both,
  each solution's mean final share and the final leaders.

      iex> alias TartarusImmune.Select.Fig64b
      iex> Fig64b.verdict([%{"QS" => 30, "ShS" => 20}, %{"QS" => 40, "ShS" => 0}]).outcome
      "reproduced"
      iex> v = Fig64b.verdict([%{"QS" => 40, "ShS" => 2}, %{"QS" => 40, "ShS" => 0}])
      iex> {v.outcome, v.with_both, v.leaders}
      {"differs", 0, %{"QS" => 2}}
  """
  @spec verdict([map()], keyword()) :: map()
  def verdict(finals, opts \\ []) do
    min = Keyword.get(opts, :min_share, 0.25)
    shares = Enum.map(finals, &shares/1)
    both = Enum.count(shares, &(Map.get(&1, "QS", 0) >= min and Map.get(&1, "ShS", 0) >= min))
    names = shares |> Enum.flat_map(&Map.keys/1) |> Enum.uniq() |> Enum.sort()

    %{
      outcome: if(2 * both >= length(finals), do: "reproduced", else: "differs"),
      with_both: both,
      runs: length(finals),
      min_share: min,
      mean_share:
        Map.new(names, fn n -> {n, Stats.mean(Enum.map(shares, &Map.get(&1, n, 0)))} end),
      leaders: finals |> Enum.map(&leader/1) |> Enum.frequencies()
    }
  end

  defp leader(pop), do: pop |> Enum.max_by(fn {s, n} -> {n, s} end) |> elem(0)
end
