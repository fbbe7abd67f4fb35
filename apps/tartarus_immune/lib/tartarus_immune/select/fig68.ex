defmodule TartarusImmune.Select.Fig68 do
  @moduledoc """
  The pre-registered danger-signal experiment (thesis Fig. 6.8; docs/immune.md, "Fig. 6.8
  pre-registered", dated 2026-11-27): its configuration, the guard against an
  uninformative configuration and the verdict, as pure functions.
  `TartarusImmune.Select` runs it (`mix tartarus.select --experiment fig6_8`).

  The configuration (`config/0`): a 50-node grid (5 x 10), P4, Table 6.1's constants
  (`TartarusImmune.Params` defaults), η 0.5, β 10, a barrage every 10 rounds, one danger
  signal per barrage with Eq. 6.4's strengths and Eq. 6.5's lifetimes
  (`signal_life: :eq6_5`), the initial population of §6.5.2 (one iPkt of each of the four
  solutions on each of 10 hosts, here 10 of the 50 chosen at random; the other 40 start
  empty, so a problem can wait), convergence share 0.9 held 30 rounds, a limit of 600
  rounds, seeds 1001-1040. Three arms (`arms/0`): with signals, without signals, without
  sharing.

  The **guard** (`guard/3`) and the **verdict** (`verdict/1`) are documented on each.
  """

  @seeds 1001..1040

  @config [
    set: :p4,
    nodes: 50,
    topology: :grid,
    eta: 0.5,
    beta: 10,
    period: 10,
    steps: 600,
    share: 0.9,
    hold: 30,
    seed_hosts: 10,
    per_node: 1,
    params: [signal_life: :eq6_5]
  ]

  @doc """
  The pre-registered configuration (options of `TartarusImmune.Experiment`, besides the
  arm's own and the seed).

      iex> c = TartarusImmune.Select.Fig68.config()
      iex> {c[:nodes], c[:set], c[:beta], c[:eta], c[:seed_hosts], c[:params]}
      {50, :p4, 10, 0.5, 10, [signal_life: :eq6_5]}
  """
  @spec config() :: keyword()
  def config, do: @config

  @doc "The pre-registered seeds: 1001-1040 (never used before by the immune experiments)."
  @spec seeds() :: Range.t()
  def seeds, do: @seeds

  @doc """
  The three arms: `{name, options}` (with signals, without signals, without sharing).

      iex> TartarusImmune.Select.Fig68.arms() |> Enum.map(&elem(&1, 0))
      ["danger", "no_danger", "no_sharing"]
  """
  @spec arms() :: [{String.t(), keyword()}]
  def arms,
    do: [
      {"danger", [danger: true]},
      {"no_danger", [danger: false]},
      {"no_sharing", [sharing: false]}
    ]

  @doc """
  Which options of `effective` (a map or keyword of the options a run used) differ from
  the pre-registered configuration, and the seeds if they differ: `[]` when the run is
  the pre-registered one.

      iex> alias TartarusImmune.Select.Fig68
      iex> Fig68.deviations(Fig68.config(), Enum.to_list(1001..1040))
      []
      iex> Fig68.deviations(Keyword.put(Fig68.config(), :beta, 5), [7])
      [:beta, :seeds]
  """
  @spec deviations(keyword() | map(), [integer()]) :: [atom()]
  def deviations(effective, seeds) do
    eff = Map.new(effective)

    keys = for {k, v} <- @config, Map.get(eff, k) != v, do: k

    if Enum.sort(seeds) == Enum.to_list(@seeds), do: keys, else: keys ++ [:seeds]
  end

  @doc """
  The barrage window of round `k`: barrage b is fired at round (b - 1) * period + 1 and
  its window runs to round b * period.

      iex> Enum.map([1, 10, 11, 12, 20, 21], &TartarusImmune.Select.Fig68.window(&1, 10))
      [1, 1, 2, 2, 2, 3]
  """
  @spec window(pos_integer(), pos_integer()) :: pos_integer()
  def window(k, period), do: div(k - 1, period) + 1

  @doc """
  The guard against an uninformative configuration (issue item 3): "if at least half of
  the runs in both signal arms converge at the first barrage where convergence is
  possible, the configuration is declared uninformative".

  `with_signals` and `without_signals` are the convergence rounds of the two signal arms
  (a run that did not converge counts at the step limit). Each round falls in a barrage
  window (`window/2`). The **first barrage where convergence is possible** is the
  earliest window by which at least `min_share` (5 %) of the pooled runs of both arms have
  converged, so that one or two lucky runs (a run converging with the first barrage, as a
  few did at round 5 in the 10-host plan) do not move it. The guard **fires** when, in
  each of the two arms, at least half of the runs converge in that window or earlier.

  Returns `%{fired:, first_barrage:, rounds:, at_first:, runs:, min_share:}` (`rounds`:
  the window's first and last round; `at_first`: per arm, the runs converged by the end
  of the window). With 40 runs an arm the first window is that of the 4th earliest of the
  80 rounds. Below, with `min_share: 0.2` the one run at round 5 does not make the first
  barrage possible; the second example converges later in most runs.

      iex> alias TartarusImmune.Select.Fig68
      iex> g = Fig68.guard([11, 12, 11, 13, 25], [12, 11, 5, 11, 31], 10, min_share: 0.2)
      iex> {g.fired, g.first_barrage, g.rounds, g.at_first}
      {true, 2, {11, 20}, {4, 4}}
      iex> Fig68.guard([11, 12, 24, 33, 25], [12, 11, 21, 31, 45], 10).fired
      false
  """
  @spec guard([number()], [number()], pos_integer(), keyword()) :: map()
  def guard(with_signals, without_signals, period, opts \\ []) do
    min_share = Keyword.get(opts, :min_share, 0.05)
    pooled = Enum.sort(with_signals ++ without_signals)
    need = max(1, ceil(min_share * length(pooled)))
    first = window(Enum.at(pooled, need - 1), period)
    by = fn xs -> Enum.count(xs, &(window(&1, period) <= first)) end
    at = {by.(with_signals), by.(without_signals)}
    half? = fn n, xs -> 2 * n >= length(xs) end

    %{
      fired: half?.(elem(at, 0), with_signals) and half?.(elem(at, 1), without_signals),
      first_barrage: first,
      rounds: {(first - 1) * period + 1, first * period},
      at_first: at,
      runs: {length(with_signals), length(without_signals)},
      min_share: min_share
    }
  end

  @doc """
  The verdict, as pre-registered (issue "Done means"): with signals the median and the
  interquartile range of the convergence rounds are lower than without, the mean is lower
  with a one-sided Mann-Whitney p < 0.05 (signals < no signals), and the no-sharing arm is
  the slowest (its median and mean above both signal arms'). `args`:

    * `:danger`, `:no_danger`, `:no_sharing` - `TartarusTools.Stats.describe/1` of each
      arm's convergence rounds;
    * `:p_value` - the one-sided Mann-Whitney p, signals < no signals;
    * `:guard` - `guard/4`'s result.

  Returns `%{outcome:, criteria:}`: `outcome` is `"uninformative"` when the guard fired
  (a finding, not a pass), else `"pass"` when every criterion holds, else `"fail"`;
  `criteria` says which held.

      iex> d = fn med, iqr, mean -> %{median: med, iqr: iqr, mean: mean} end
      iex> v = TartarusImmune.Select.Fig68.verdict(danger: d.(12, 2, 13.0), no_danger: d.(15, 6, 17.0),
      ...>   no_sharing: d.(40, 20, 45.0), p_value: 0.01, guard: %{fired: false})
      iex> v.outcome
      "pass"
      iex> TartarusImmune.Select.Fig68.verdict(danger: d.(12, 7, 13.0), no_danger: d.(15, 6, 17.0),
      ...>   no_sharing: d.(40, 20, 45.0), p_value: 0.01, guard: %{fired: false}).criteria.iqr_lower
      false
  """
  @spec verdict(keyword()) :: %{outcome: String.t(), criteria: map()}
  def verdict(args) do
    [a, b, c] = Enum.map([:danger, :no_danger, :no_sharing], &Keyword.fetch!(args, &1))
    p = Keyword.fetch!(args, :p_value)

    criteria = %{
      median_lower: a.median < b.median,
      iqr_lower: a.iqr < b.iqr,
      mean_lower: a.mean < b.mean,
      p_below_0_05: p < 0.05,
      no_sharing_slowest: c.median > max(a.median, b.median) and c.mean > max(a.mean, b.mean)
    }

    outcome =
      cond do
        Keyword.fetch!(args, :guard).fired -> "uninformative"
        Enum.all?(Map.values(criteria)) -> "pass"
        true -> "fail"
      end

    %{outcome: outcome, criteria: criteria}
  end
end
