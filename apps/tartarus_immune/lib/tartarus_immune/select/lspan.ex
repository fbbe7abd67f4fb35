defmodule TartarusImmune.Select.Lspan do
  @moduledoc """
  Fig. 6.8's sensitivity to the signal's span, pre-registered (docs/immune.md, "Fig. 6.4b,
  the secondary response and l_span, pre-registered", dated 2026-12-06).
  `TartarusImmune.Select` runs it (`mix tartarus.select --experiment lspan`).

  The thesis (§6.5.8): "If such signals were to be diffused farther into the network, the
  amount of time taken by the pertinent iPkt to reach the distressed node would be
  drastically reduced." The configuration is the pre-registered Fig. 6.8's
  (`TartarusImmune.Select.Fig68.config/0`: P4, a 50-host grid, β 10, Eq. 6.5's lifetimes,
  the initial iPkts on 10 random hosts) with four arms (`arms/0`): signals of span
  `l_span` 2 (Table 6.1's: one hop), 3 and 4 (Eq. 6.4: 100, 66.7, 33.3 and 100, 75, 50, 25,
  reaching two and three hops), and no signals. Each run measures directly
  (`TartarusImmune.Experiment`'s `reach: true`), for every distressed host of every
  barrage, the **reach time**: the rounds until an iPkt that recognizes one of its pending
  problems is resident on it (0: one was there when the barrage came). A host not reached
  before its next barrage or the run's end is censored; a run's measure is its mean reach
  time with every time capped at the period (10 rounds; `reach_mean/2`). The verdict is
  `verdict/1`. Fig. 6.8's η 0.5 makes 25 of the 50 hosts distressed at once, so nearly
  every host is within one hop of one; the same arms with η 0.1 (`--eta 0.1`, 5 distressed
  hosts) are the second pre-registered configuration, where a span can matter.
  """

  alias TartarusImmune.Select.Fig68
  alias TartarusTools.Stats

  @seeds 4001..4020

  @doc """
  The four arms: `{name, options}`.

      iex> TartarusImmune.Select.Lspan.arms() |> Enum.map(&elem(&1, 0))
      ["l_span_2", "l_span_3", "l_span_4", "no_danger"]
  """
  @spec arms() :: [{String.t(), keyword()}]
  def arms do
    life = Fig68.config()[:params]

    for(l <- [2, 3, 4], do: {"l_span_#{l}", [danger: true, params: life ++ [l_span: l]]}) ++
      [{"no_danger", [danger: false, params: life]}]
  end

  @doc "The pre-registered seeds: 4001-4020 (never used before)."
  @spec seeds() :: Range.t()
  def seeds, do: @seeds

  @doc """
  A run's mean reach time, each time capped at `period` rounds: the reach times of its
  served hosts, and its censored hosts counted as `period`. `nil` for a run with no
  distressed host.

      iex> TartarusImmune.Select.Lspan.reach_mean(%{times: [0, 2, 4, 14], censored: [7]}, 10)
      5.2
      iex> TartarusImmune.Select.Lspan.reach_mean(%{times: [], censored: []}, 10)
      nil
  """
  @spec reach_mean(%{times: [number()], censored: [number()]} | nil, pos_integer()) ::
          float() | nil
  def reach_mean(nil, _period), do: nil

  def reach_mean(%{times: ts, censored: cs}, period) do
    case Enum.map(ts, &min(&1, period)) ++ Enum.map(cs, fn _ -> period end) do
      [] -> nil
      xs -> Stats.mean(xs) * 1.0
    end
  end

  @doc """
  The verdict, as pre-registered, on the runs' mean reach times per arm (`reach`: arm name
  -> `[mean]`, one per seed), and the one-sided Mann-Whitney p-values `p_4_less_2` (l_span
  4 < 2) and `p_2_less_none` (l_span 2 < no signals). The outcome is `"reproduced"` when
  (1) the arms' medians fall strictly with the span, 2 > 3 > 4, (2) `p_4_less_2` < 0.05,
  and (3) l_span 2's median is below no signals' with `p_2_less_none` < 0.05; `"differs"`
  otherwise (`criteria` says which held).

      iex> r = %{"l_span_2" => [3, 4, 5], "l_span_3" => [2, 3, 4], "l_span_4" => [1, 2, 3], "no_danger" => [6, 7, 8]}
      iex> TartarusImmune.Select.Lspan.verdict(r, 0.01, 0.01).outcome
      "reproduced"
      iex> TartarusImmune.Select.Lspan.verdict(r, 0.2, 0.01).criteria.p_4_less_2
      false
  """
  @spec verdict(%{String.t() => [number()]}, float(), float()) :: map()
  def verdict(reach, p_4_less_2, p_2_less_none) do
    med = Map.new(reach, fn {a, xs} -> {a, Stats.median_mid(Enum.reject(xs, &is_nil/1))} end)

    criteria = %{
      falls_with_span: med["l_span_2"] > med["l_span_3"] and med["l_span_3"] > med["l_span_4"],
      p_4_less_2: p_4_less_2 < 0.05,
      signals_sooner: med["l_span_2"] < med["no_danger"] and p_2_less_none < 0.05
    }

    %{
      outcome: if(Enum.all?(Map.values(criteria)), do: "reproduced", else: "differs"),
      criteria: criteria,
      medians: med
    }
  end
end
