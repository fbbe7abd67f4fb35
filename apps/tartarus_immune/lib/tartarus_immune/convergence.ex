defmodule TartarusImmune.Convergence do
  @moduledoc """
  When a run has converged, the one definition every experiment uses.

  At step `k` the **leader** is the solution with the strictly largest number of live iPkts
  in the whole network, provided its **share** of all live iPkts is at least `share`
  (default 0.5); otherwise there is no leader. A run **converges at step k*** when the same
  solution leads at every step `k*, k* + 1, ..., k* + hold - 1` (`hold` default 30). That
  solution is the run's **winner** and `k*` its **convergence step**. The stopping
  criterion of §6.5.2 is "converged" (known at step `k* + hold - 1`) or the step limit.

  Without sharing the same rule is applied to the network-wide population (the sum over
  the isolated nodes).

      iex> c = TartarusImmune.Convergence.new(share: 0.5, hold: 2)
      iex> c = TartarusImmune.Convergence.observe(c, 1, %{"IS" => 2, "QS" => 2})
      iex> c = TartarusImmune.Convergence.observe(c, 2, %{"IS" => 3, "QS" => 2})
      iex> c.converged
      nil
      iex> c = TartarusImmune.Convergence.observe(c, 3, %{"IS" => 4, "QS" => 1})
      iex> c.converged
      {2, "IS"}
  """

  defstruct share: 0.5, hold: 30, leader: nil, since: nil, converged: nil

  @type t :: %__MODULE__{
          share: number(),
          hold: pos_integer(),
          leader: term(),
          since: pos_integer() | nil,
          converged: {pos_integer(), term()} | nil
        }

  @doc "A fresh tracker. Options: `:share` (0.5), `:hold` (30)."
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    %__MODULE__{share: Keyword.get(opts, :share, 0.5), hold: Keyword.get(opts, :hold, 30)}
  end

  @doc """
  The leader of a population map (solution => count), or nil.

      iex> TartarusImmune.Convergence.leader(%{"a" => 3, "b" => 3}, 0.1)
      nil
      iex> TartarusImmune.Convergence.leader(%{"a" => 4, "b" => 3}, 0.5)
      "a"
      iex> TartarusImmune.Convergence.leader(%{"a" => 4, "b" => 3, "c" => 2}, 0.5)
      nil
  """
  @spec leader(map(), number()) :: term() | nil
  def leader(pop, share) do
    total = pop |> Map.values() |> Enum.sum()

    case pop |> Enum.sort_by(fn {s, n} -> {-n, s} end) do
      [{s, n}, {_, m} | _] when n > m and total > 0 and n / total >= share -> s
      [{s, n}] when n > 0 -> s
      _ -> nil
    end
  end

  @doc "Observes the population at step `k` (steps must come in order)."
  @spec observe(t(), pos_integer(), map()) :: t()
  def observe(%__MODULE__{converged: c} = t, _k, _pop) when c != nil, do: t

  def observe(t, k, pop) do
    case leader(pop, t.share) do
      nil ->
        %{t | leader: nil, since: nil}

      l ->
        since = if l == t.leader, do: t.since, else: k
        t = %{t | leader: l, since: since}
        if k - since + 1 >= t.hold, do: %{t | converged: {since, l}}, else: t
    end
  end

  @doc """
  The convergence of a whole series `[{k, pop}]`: `{k*, winner}` or nil.

      iex> s = [{1, %{"a" => 1, "b" => 1}}, {2, %{"a" => 2, "b" => 1}}, {3, %{"a" => 3, "b" => 1}}]
      iex> TartarusImmune.Convergence.of_series(s, share: 0.6, hold: 2)
      {2, "a"}
  """
  @spec of_series([{pos_integer(), map()}], keyword()) :: {pos_integer(), term()} | nil
  def of_series(series, opts \\ []) do
    Enum.reduce(series, new(opts), fn {k, pop}, t -> observe(t, k, pop) end).converged
  end
end
