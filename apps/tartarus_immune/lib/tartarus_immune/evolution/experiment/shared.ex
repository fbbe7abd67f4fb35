defmodule TartarusImmune.Evolution.Experiment.Shared do
  @moduledoc """
  What the embodied-evolution experiments (`TartarusImmune.Evolution.Experiment` and its
  per-experiment modules) share: the sharing schemes, their labels, the summaries' means.
  """

  alias TartarusTools.Stats

  @doc """
  The schemes compared on an n-node network: no sharing (the baseline: how fast the
  nodes get there on their own), broadcast, then iPkts in three numbers proportional to n.

      iex> TartarusImmune.Evolution.Experiment.Shared.schemes(20)
      [:none, :broadcast, {:ipkt, 1}, {:ipkt, 2}, {:ipkt, 4}]
      iex> TartarusImmune.Evolution.Experiment.Shared.schemes(80)
      [:none, :broadcast, {:ipkt, 4}, {:ipkt, 8}, {:ipkt, 16}]
  """
  @spec schemes(pos_integer()) :: [:none | :broadcast | {:ipkt, pos_integer()}]
  def schemes(n),
    do: [:none, :broadcast | Enum.map([20, 10, 5], &{:ipkt, max(1, div(n, &1))})] |> Enum.uniq()

  @doc "A scheme's label: `none`, `b-cast` or `iPkt-x`."
  @spec label(:none | :broadcast | {:ipkt, pos_integer()}) :: String.t()
  def label(:none), do: "none"
  def label(:broadcast), do: "b-cast"
  def label({:ipkt, x}), do: "iPkt-#{x}"

  @doc """
  One run of the sharing experiment (`TartarusImmune.Evolution.Sharing.run/1`) of `n`
  nodes with `scheme` on `seed`, under the experiment's options `p` (`p`,
  `max_iterations`, `mode`, `seed`) and `extra` options of the run; the result gets the
  scheme's `label` and the `trial` (`seed - p.seed`).
  """
  @spec run_scheme(pos_integer(), term(), integer(), map(), keyword()) :: map()
  def run_scheme(n, scheme, seed, p, extra \\ []) do
    {kind, x} = if is_atom(scheme), do: {scheme, 1}, else: scheme

    {:ok, r} =
      TartarusImmune.Evolution.Sharing.run(
        [
          nodes: n,
          scheme: kind,
          ipkts: x,
          p: p.p,
          max_iterations: p.max_iterations,
          mode: p.mode,
          seed: seed
        ] ++ extra
      )

    Map.merge(r, %{label: label(scheme), trial: seed - p.seed})
  end

  @doc false
  # the mean to 2 decimals, nil for none (the experiments' summaries)
  @spec mean2([number()]) :: float() | nil
  def mean2(xs), do: (m = Stats.mean(xs)) && Float.round(m, 2)
end
