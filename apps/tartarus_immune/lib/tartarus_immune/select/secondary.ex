defmodule TartarusImmune.Select.Secondary do
  @moduledoc """
  Thesis Fig. 6.3a's secondary response, pre-registered (docs/immune.md, "Fig. 6.4b, the
  secondary response and l_span, pre-registered", dated 2026-12-06). `TartarusImmune.Select`
  runs it (`mix tartarus.select --experiment secondary`).

  The thesis (§6.5.2, P1): "At step-count = 850, a copy of a previously fired barrage of
  antigens was introduced in the network causing a secondary response". Here (`config/0`):
  P1 on a 10-host grid with one iPkt of every solution on every host, β 5, η 0.5; **one**
  barrage at round 1 (the primary), then no barrage until the population has settled
  (nothing is pending, so nobody interacts), and at round 61 a **copy** of it: the same
  instances at the same hosts (`TartarusImmune.Experiment`'s `repeat:`); 120 rounds in all.
  The signal of a barrage is followed for its period (10 rounds), as in every experiment.

  The measure (`measure/3`, per run): the **losers** are the solutions other than the
  **winner**, the leader just before the copy (round 60); for each barrage, the losers'
  count just before it (the initial population for the first) and the **time to
  suppression**, the rounds until the losers are at most half of that count (the barrage's
  round counts 1; `nil` if not within the 60 rounds of its phase, or if there were no
  losers); and the winner's response, its largest gain in the 10 rounds of the barrage's
  period. The verdict is `verdict/1`.
  """

  alias TartarusTools.{Series, Stats}

  @seeds 3001..3030

  @config [
    set: :p1,
    nodes: 10,
    topology: :grid,
    eta: 0.5,
    beta: 5,
    period: 10,
    steps: 120,
    barrages: [1],
    repeat: [{61, 1}]
  ]

  @doc """
  The pre-registered configuration: the options of `TartarusImmune.Experiment`.

      iex> c = TartarusImmune.Select.Secondary.config()
      iex> {c[:barrages], c[:repeat], c[:steps]}
      {[1], [{61, 1}], 120}
  """
  @spec config() :: keyword()
  def config, do: @config

  @doc "The pre-registered seeds: 3001-3030 (never used before)."
  @spec seeds() :: Range.t()
  def seeds, do: @seeds

  @doc """
  A run's measure from its learning curve `series` (`TartarusTools.Series`: live iPkts per
  solution per round; a `"total"` series is ignored) and its `initial` population (name ->
  count). The barrages are at rounds `b1` and `b2` (`b1 < b2`); each phase ends before the
  next barrage or at the last round.

      iex> alias TartarusTools.Series
      iex> s = Enum.reduce([{1, 5, 3}, {2, 7, 1}, {3, 8, 1}, {4, 9, 1}, {5, 9, 0}], Series.new(),
      ...>   fn {k, w, l}, s -> s |> Series.record("IS", k, w) |> Series.record("SelS", k, l) end)
      iex> m = TartarusImmune.Select.Secondary.measure(s, %{"IS" => 4, "SelS" => 4}, {1, 4})
      iex> {m.winner, m.losers_before, m.suppression, m.winner_gain}
      {"IS", [4, 1], [2, 2], [4, 1]}
  """
  @spec measure(Series.t(), map(), {pos_integer(), pos_integer()}) :: map()
  def measure(series, initial, {b1, b2}) do
    names = series |> Series.names() |> Enum.map(&to_string/1) |> Enum.reject(&(&1 == "total"))
    pop = fn k -> Map.new(names, &{&1, value(series, &1, k, initial)}) end
    before2 = pop.(b2 - 1)
    winner = before2 |> Enum.max_by(fn {s, n} -> {n, s} end) |> elem(0)
    losers = fn k -> pop.(k) |> Map.delete(winner) |> Map.values() |> Enum.sum() end
    last = series |> Series.points(hd(names)) |> List.last() |> elem(0)
    phases = [{b1, b2 - 1}, {b2, last}]
    before = Enum.map(phases, fn {b, _} -> losers.(b - 1) end)

    %{
      winner: winner,
      losers_before: before,
      suppression:
        Enum.zip_with(phases, before, fn
          _, 0 ->
            nil

          {b, e}, l0 ->
            Enum.find_value(b..e, fn k -> if 2 * losers.(k) <= l0, do: k - b + 1 end)
        end),
      winner_gain:
        Enum.map(phases, fn {b, e} ->
          w0 = Map.fetch!(pop.(b - 1), winner)
          peak = b..min(e, b + 9) |> Enum.map(&Map.fetch!(pop.(&1), winner)) |> Enum.max()
          peak - w0
        end)
    }
  end

  # the count of `name` at round k (round 0: the initial population)
  defp value(_series, name, 0, initial), do: Map.get(initial, name, 0)

  defp value(series, name, k, _initial) do
    series |> Series.points(name) |> List.keyfind(k, 0) |> elem(1)
  end

  @doc """
  The verdict, as pre-registered, over the runs' `measure/3`s. The **informative** runs
  are those with losers before both barrages. A run's time to suppression that is `nil`
  (not halved within its phase) counts as 61 (longer than any phase). The outcome:

    * `"uninformative"` if fewer than a third of the runs are informative (the primary
      barrage alone suppressed the losers: nothing left to compare);
    * `"reproduced"` if, over the informative runs, the median time to suppression is
      lower for the copy than for the first barrage **and** the copy is faster in more runs
      than it is slower (a sign count);
    * `"differs"` otherwise.

  Also returned: the times per barrage (described), the sign counts, and the winners.

      iex> alias TartarusImmune.Select.Secondary
      iex> m = fn s1, s2 -> %{winner: "IS", losers_before: [30, 4], suppression: [s1, s2], winner_gain: [5, 9]} end
      iex> Secondary.verdict([m.(5, 2), m.(4, 1), m.(6, 7)]).outcome
      "reproduced"
      iex> Secondary.verdict([m.(5, 9), m.(4, nil), m.(6, 2)]).outcome
      "differs"
      iex> Secondary.verdict([%{winner: "IS", losers_before: [30, 0], suppression: [3, nil], winner_gain: [1, 0]}]).outcome
      "uninformative"
  """
  @spec verdict([map()]) :: map()
  def verdict(measures) do
    inf = Enum.filter(measures, fn m -> Enum.all?(m.losers_before, &(&1 > 0)) end)
    t = fn i -> Enum.map(inf, &(Enum.at(&1.suppression, i) || 61)) end
    {t1, t2} = {t.(0), t.(1)}
    pairs = Enum.zip(t1, t2)
    faster = Enum.count(pairs, fn {a, b} -> b < a end)
    slower = Enum.count(pairs, fn {a, b} -> b > a end)

    outcome =
      cond do
        3 * length(inf) < length(measures) -> "uninformative"
        Stats.median(t2) < Stats.median(t1) and faster > slower -> "reproduced"
        true -> "differs"
      end

    %{
      outcome: outcome,
      runs: length(measures),
      informative: length(inf),
      suppression_first: Stats.describe(t1),
      suppression_second: Stats.describe(t2),
      second_faster: faster,
      second_slower: slower,
      ties: length(pairs) - faster - slower,
      losers_before_first: Stats.describe(Enum.map(measures, &hd(&1.losers_before))),
      losers_before_second: Stats.describe(Enum.map(measures, &List.last(&1.losers_before))),
      winner_gain_first: Stats.describe(Enum.map(measures, &hd(&1.winner_gain))),
      winner_gain_second: Stats.describe(Enum.map(measures, &List.last(&1.winner_gain))),
      winners: measures |> Enum.map(& &1.winner) |> Enum.frequencies()
    }
  end
end
