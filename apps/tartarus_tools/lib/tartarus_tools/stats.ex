defmodule TartarusTools.Stats do
  @moduledoc """
  The statistics of the experiments, in one place: mean, standard deviation, nearest-rank
  quantiles (median, quartiles, IQR), box-plot statistics, a per-sample summary and the
  one-sided Mann-Whitney U test between two samples. Pure functions on lists of numbers.

  Conventions, so that a number means the same in every report:

    * **quantiles are nearest rank**: `percentile(xs, q)` is an actual sample (the
      `ceil(q * n)`-th smallest), never an interpolation; the median of an even count is
      the lower middle sample. The same definition as the platform's hop statistics, and
      what every report's `median` key gives.
    * **charts draw the conventional median**, `median_mid/1`: the mean of the two middle
      samples of an even count (of [11, 13], 12.0). `describe/1` gives both (`median`,
      `median_mid`), so a chart's median line can be read back from the report.
    * **`sd/1` is the sample standard deviation** (divisor `n - 1`), `nil` below two samples.
    * **empty lists give `nil`** (`mean/1`, `median/1`, `percentile/2`, `box/1`, ...), so
      an arm with no runs shows as empty rather than as zero.
    * `mean/1` is `Enum.sum(xs) / length(xs)`, in that order, so the floats are bit for bit
      those of the copies it replaced.

      iex> alias TartarusTools.Stats
      iex> xs = [3, 1, 4, 1, 5, 9, 2, 6]
      iex> {Stats.mean(xs), Stats.median(xs), Stats.iqr(xs)}
      {3.875, 3, 4}
      iex> Stats.mann_whitney([0.9, 0.8, 0.7], [0.1, 0.2, 0.3]).p_value |> Float.round(4)
      0.05
  """

  @typedoc "Box-plot statistics of one sample (Tukey: whiskers reach 1.5 IQR)."
  @type box :: %{
          n: pos_integer,
          min: number,
          max: number,
          q1: number,
          median: number,
          q3: number,
          whisker_low: number,
          whisker_high: number,
          outliers: [number]
        }

  @typedoc "What `describe/1` returns."
  @type description :: %{
          n: non_neg_integer,
          mean: float | nil,
          sd: float | nil,
          median: number | nil,
          median_mid: number | nil,
          q1: number | nil,
          q3: number | nil,
          iqr: number | nil,
          min: number | nil,
          max: number | nil
        }

  @typedoc """
  A Mann-Whitney outcome: `u` of the first sample, the one-sided `p_value`, the sizes and
  the `method` (`:exact` or `:normal`).
  """
  @type mann_whitney :: %{
          u: float,
          p_value: float,
          n1: non_neg_integer,
          n2: non_neg_integer,
          method: :exact | :normal
        }

  @exact_max 20

  @doc """
  The arithmetic mean, `nil` for an empty list.

      iex> TartarusTools.Stats.mean([1, 2, 3, 4])
      2.5
      iex> TartarusTools.Stats.mean([])
      nil
  """
  @spec mean([number]) :: float | nil
  def mean([]), do: nil
  def mean(xs) when is_list(xs), do: Enum.sum(xs) / length(xs)

  @doc """
  The sample variance (divisor `n - 1`), `nil` below two samples.

      iex> TartarusTools.Stats.variance([2, 4, 4, 4, 5, 5, 7, 9])
      4.571428571428571
      iex> TartarusTools.Stats.variance([1])
      nil
  """
  @spec variance([number]) :: float | nil
  def variance(xs) when is_list(xs) and length(xs) < 2, do: nil

  def variance(xs) when is_list(xs) do
    m = mean(xs)
    Enum.sum(Enum.map(xs, &((&1 - m) * (&1 - m)))) / (length(xs) - 1)
  end

  @doc """
  The sample standard deviation (divisor `n - 1`), `nil` below two samples.

      iex> TartarusTools.Stats.sd([2, 4, 4, 4, 5, 5, 7, 9]) |> Float.round(4)
      2.1381
      iex> TartarusTools.Stats.sd([5])
      nil
  """
  @spec sd([number]) :: float | nil
  def sd(xs) when is_list(xs) do
    case variance(xs) do
      nil -> nil
      v -> :math.sqrt(v)
    end
  end

  @doc """
  The mean with its two-sided 95 % confidence interval (Student's t with `n - 1` degrees
  of freedom: `mean ± t * sd / sqrt(n)`), what a chart of means over trials draws as error
  bars. `nil` for an empty list; a single sample has no interval (`lo` and `hi` are `nil`).
  Degrees of freedom above 30 use the tabulated value of the next lower entry (30, 40, 60,
  120), so the interval is never narrower than the exact one.

      iex> ci = TartarusTools.Stats.mean_ci([10, 12, 14])
      iex> {ci.n, ci.mean, ci.sd, Float.round(ci.lo, 3), Float.round(ci.hi, 3)}
      {3, 12.0, 2.0, 7.031, 16.969}
      iex> TartarusTools.Stats.mean_ci([5]).hi
      nil
      iex> TartarusTools.Stats.mean_ci([])
      nil
  """
  @spec mean_ci([number]) ::
          %{
            n: pos_integer,
            mean: float,
            sd: float | nil,
            half_width: float | nil,
            lo: float | nil,
            hi: float | nil
          }
          | nil
  def mean_ci([]), do: nil

  def mean_ci(xs) when is_list(xs) do
    n = length(xs)
    m = mean(xs)

    case sd(xs) do
      nil ->
        %{n: n, mean: m, sd: nil, half_width: nil, lo: nil, hi: nil}

      s ->
        h = Float.round(t975(n - 1) * s / :math.sqrt(n), 6)
        %{n: n, mean: m, sd: s, half_width: h, lo: m - h, hi: m + h}
    end
  end

  @t975 {12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179,
         2.160, 2.145, 2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064,
         2.060, 2.056, 2.052, 2.048, 2.045, 2.042}

  # The 0.975 quantile of Student's t with `df` degrees of freedom (two-sided 95 %).
  defp t975(df) when df <= 30, do: elem(@t975, df - 1)
  defp t975(df) when df < 40, do: 2.042
  defp t975(df) when df < 60, do: 2.021
  defp t975(df) when df < 120, do: 2.000
  defp t975(_df), do: 1.980

  @doc """
  The value at quantile `q` (0..1), by nearest rank: the `ceil(q * n)`-th smallest sample
  (at least the first), an actual sample; `nil` for an empty list. `xs` need not be sorted.

      iex> TartarusTools.Stats.percentile([5, 1, 4, 2, 3], 0.5)
      3
      iex> TartarusTools.Stats.percentile([4, 1, 3, 2], 0.5)
      2
      iex> TartarusTools.Stats.percentile([1, 2, 3, 4, 100], 0.99)
      100
      iex> TartarusTools.Stats.percentile([7, 8], 0.0)
      7
      iex> TartarusTools.Stats.percentile([], 0.5)
      nil
  """
  @spec percentile([number], number) :: number | nil
  def percentile([], _q), do: nil

  def percentile(xs, q) when is_list(xs) and is_number(q) and q >= 0 and q <= 1,
    do: Tartarus.Percentile.of(xs, q)

  @doc """
  Several quantiles at once (one sort), in the order of `qs`; `nil`s for an empty list.

      iex> TartarusTools.Stats.quantiles([9, 1, 8, 2, 7, 3, 6, 4, 5], [0.25, 0.5, 0.75])
      [3, 5, 7]
      iex> TartarusTools.Stats.quantiles([], [0.5])
      [nil]
  """
  @spec quantiles([number], [number]) :: [number | nil]
  def quantiles([], qs), do: Enum.map(qs, fn _ -> nil end)

  def quantiles(xs, qs) when is_list(xs) and is_list(qs) do
    sorted = Enum.sort(xs)
    Enum.map(qs, &sorted_percentile(sorted, &1))
  end

  @doc """
  The median, `percentile(xs, 0.5)`: the lower middle sample of an even count; `nil` for
  an empty list.

      iex> TartarusTools.Stats.median([3, 1, 2])
      2
      iex> TartarusTools.Stats.median([1, 2, 3, 4])
      2
  """
  @spec median([number]) :: number | nil
  def median(xs), do: percentile(xs, 0.5)

  @doc """
  The conventional median: the middle sample of an odd count, the mean of the two middle
  samples of an even count; `nil` for an empty list. What the charts draw (box plots'
  median line); `median/1`, nearest rank, is what the reports' `median` keys give.

      iex> TartarusTools.Stats.median_mid([13, 11])
      12.0
      iex> TartarusTools.Stats.median_mid([3, 1, 2])
      2
      iex> TartarusTools.Stats.median_mid([])
      nil
  """
  @spec median_mid([number]) :: number | nil
  def median_mid([]), do: nil
  def median_mid(xs) when is_list(xs), do: sorted_median_mid(Enum.sort(xs))

  defp sorted_median_mid(sorted) do
    n = length(sorted)

    if rem(n, 2) == 1,
      do: Enum.at(sorted, div(n, 2)),
      else: (Enum.at(sorted, div(n, 2) - 1) + Enum.at(sorted, div(n, 2))) / 2
  end

  @doc """
  The interquartile range, `q3 - q1` (nearest-rank quartiles), `nil` for an empty list.

      iex> TartarusTools.Stats.iqr(Enum.to_list(1..9))
      4
  """
  @spec iqr([number]) :: number | nil
  def iqr([]), do: nil

  def iqr(xs) do
    [q1, q3] = quantiles(xs, [0.25, 0.75])
    q3 - q1
  end

  @doc """
  Box-plot statistics, or `nil` for an empty list: nearest-rank quartiles and median;
  whiskers reach the most extreme samples within 1.5 IQR of the box; samples beyond are
  outliers (Tukey). Raises `ArgumentError` on an element that is not a number.
  `median: :mid` gives the conventional median instead (`median_mid/1`), what a chart draws.

      iex> TartarusTools.Stats.box([1, 2, 3, 4, 100])
      %{n: 5, min: 1, max: 100, q1: 2, median: 3, q3: 4, whisker_low: 1, whisker_high: 4, outliers: [100]}
      iex> TartarusTools.Stats.box([11, 13]).median
      11
      iex> TartarusTools.Stats.box([11, 13], median: :mid).median
      12.0
      iex> TartarusTools.Stats.box([])
      nil
  """
  @spec box([number], keyword) :: box | nil
  def box(xs, opts \\ [])
  def box([], _opts), do: nil

  def box(xs, opts) when is_list(xs) do
    Enum.each(xs, fn s ->
      if not is_number(s) do
        raise ArgumentError,
              "Stats.box/1: expected a list of numbers, got an element: #{inspect(s)}"
      end
    end)

    sorted = Enum.sort(xs)
    [q1, median, q3] = Enum.map([0.25, 0.5, 0.75], &sorted_percentile(sorted, &1))
    median = if Keyword.get(opts, :median) == :mid, do: sorted_median_mid(sorted), else: median
    iqr = q3 - q1
    inside? = &(&1 >= q1 - 1.5 * iqr and &1 <= q3 + 1.5 * iqr)
    inside = Enum.filter(sorted, inside?)

    %{
      n: length(sorted),
      min: hd(sorted),
      max: List.last(sorted),
      q1: q1,
      median: median,
      q3: q3,
      whisker_low: hd(inside),
      whisker_high: List.last(inside),
      outliers: Enum.reject(sorted, inside?)
    }
  end

  @doc """
  A description of one sample: `n`, `mean`, `sd`, `median` (nearest rank), `median_mid`
  (the conventional median, what a box plot's median line shows), `q1`, `q3`, `iqr`,
  `min`, `max` (what a sweep reports per arm and metric). `nil` values are dropped first
  (a run that did not produce the metric), so `n` counts the numbers described.

      iex> TartarusTools.Stats.describe([4, 1, nil, 3, 2])
      %{n: 4, mean: 2.5, sd: 1.2909944487358056, median: 2, median_mid: 2.5, q1: 1, q3: 3, iqr: 2, min: 1, max: 4}
      iex> TartarusTools.Stats.describe([]).median
      nil
  """
  @spec describe([number | nil]) :: description
  def describe(xs) when is_list(xs) do
    xs = Enum.reject(xs, &is_nil/1)
    [q1, median, q3] = quantiles(xs, [0.25, 0.5, 0.75])

    %{
      n: length(xs),
      mean: mean(xs),
      sd: sd(xs),
      median: median,
      median_mid: median_mid(xs),
      q1: q1,
      q3: q3,
      iqr: if(q1, do: q3 - q1),
      min: if(xs == [], do: nil, else: Enum.min(xs)),
      max: if(xs == [], do: nil, else: Enum.max(xs))
    }
  end

  @doc """
  One-sided Mann-Whitney U (Wilcoxon rank-sum) test that `xs` is stochastically
  **larger** than `ys` (pass `alternative: :less` for smaller).

  `u` counts the pairs `(x, y)` with `x > y`, ties counting one half (`n1 * n2` when every
  x beats every y). The p-value is

    * **exact** (`method: :exact`) when both samples have at most #{@exact_max} values:
      the permutation distribution of the first sample's rank sum over all splits of the
      pooled values, conditional on the ties (mid-ranks), counted by dynamic programming;
      with few runs per arm and many ties the normal approximation is poor;
    * the **normal approximation** (`method: :normal`) above that: z of U with the tie
      correction of the variance and a continuity correction of 1/2.

  `:method` forces either. Empty samples give `p_value` 1.0.

      iex> r = TartarusTools.Stats.mann_whitney([1, 1, 0], [0, 0, 0])
      iex> {r.u, Float.round(r.p_value, 3), r.method}
      {7.5, 0.2, :exact}
      iex> TartarusTools.Stats.mann_whitney([0.1, 0.2, 0.3], [0.9, 0.8, 0.7]).p_value
      1.0
      iex> TartarusTools.Stats.mann_whitney([0.1, 0.2, 0.3], [0.9, 0.8, 0.7], alternative: :less).p_value |> Float.round(4)
      0.05
      iex> r = TartarusTools.Stats.mann_whitney(Enum.to_list(11..40), Enum.to_list(1..30))
      iex> {r.method, r.p_value < 0.01}
      {:normal, true}
  """
  @spec mann_whitney([number], [number], keyword) :: mann_whitney
  def mann_whitney(xs, ys, opts \\ []) when is_list(xs) and is_list(ys) do
    case Keyword.get(opts, :alternative, :greater) do
      :greater ->
        greater(xs, ys, opts)

      :less ->
        r = greater(ys, xs, opts)
        %{r | u: r.n1 * r.n2 - r.u, n1: r.n2, n2: r.n1}
    end
  end

  defp greater(xs, ys, opts) do
    n1 = length(xs)
    n2 = length(ys)

    method =
      Keyword.get_lazy(opts, :method, fn ->
        if n1 <= @exact_max and n2 <= @exact_max, do: :exact, else: :normal
      end)

    if n1 == 0 or n2 == 0 do
      %{u: 0.0, p_value: 1.0, n1: n1, n2: n2, method: method}
    else
      u =
        Enum.reduce(xs, 0.0, fn x, acc ->
          Enum.reduce(ys, acc, fn
            y, a when x > y -> a + 1.0
            y, a when x == y -> a + 0.5
            _, a -> a
          end)
        end)

      p = if method == :exact, do: exact_p(xs, ys), else: normal_p(u, xs, ys)
      %{u: u, p_value: p, n1: n1, n2: n2, method: method}
    end
  end

  defp exact_p(xs, ys) do
    # doubled mid-ranks of the pooled sample: integers
    pooled = Enum.map(xs, &{&1 * 1.0, :x}) ++ Enum.map(ys, &{&1 * 1.0, :y})
    ranks2 = doubled_ranks(pooled)

    observed =
      pooled
      |> Enum.zip(ranks2)
      |> Enum.filter(fn {{_, g}, _} -> g == :x end)
      |> Enum.map(&elem(&1, 1))
      |> Enum.sum()

    counts = rank_sum_counts(ranks2, length(xs))
    total = counts |> Map.values() |> Enum.sum()
    tail = counts |> Enum.filter(fn {s, _} -> s >= observed end) |> Enum.map(&elem(&1, 1))
    Enum.sum(tail) / total
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
    ranks2
    |> Enum.reduce(%{{0, 0} => 1}, fn r, table ->
      Enum.reduce(table, table, fn {{j, s}, c}, acc ->
        if j < k, do: Map.update(acc, {j + 1, s + r}, c, &(&1 + c)), else: acc
      end)
    end)
    |> Enum.filter(fn {{j, _}, _} -> j == k end)
    |> Map.new(fn {{_, s}, c} -> {s, c} end)
  end

  defp normal_p(u, xs, ys) do
    n1 = length(xs)
    n2 = length(ys)
    n = n1 + n2
    ties = (xs ++ ys) |> Enum.map(&(&1 * 1.0)) |> Enum.frequencies() |> Map.values()
    tie_term = Enum.sum(Enum.map(ties, &(&1 * &1 * &1 - &1))) / (n * (n - 1))
    var = n1 * n2 / 12 * (n + 1 - tie_term)

    if var <= 0 do
      1.0
    else
      z = (u - n1 * n2 / 2 - 0.5) / :math.sqrt(var)
      0.5 * :math.erfc(z / :math.sqrt(2))
    end
  end

  @doc """
  The least-squares hinge (broken-line) fit of `points` (`{x, y}`): `y = a + b *
  max(0, x - knee)`, flat up to the knee, then a line of slope `b`. The knee is searched
  from the smallest to the largest x in steps of `:step` (default 0.5); for each, `a` and
  `b` are the ordinary least squares of y on `max(0, x - knee)`; the knee with the least
  sum of squared residuals wins (the first on a tie). Returns `%{knee:, a:, b:, sse:}`, or
  nil for fewer than three distinct x.

      iex> pts = [{5, 10.0}, {10, 10.0}, {20, 10.0}, {30, 15.0}, {40, 20.0}]
      iex> TartarusTools.Stats.hinge_fit(pts)
      %{knee: 20.0, a: 10.0, b: 0.5, sse: 0.0}
      iex> TartarusTools.Stats.hinge_fit([{1, 1.0}, {2, 2.0}])
      nil
  """
  @spec hinge_fit([{number, number}], keyword) ::
          %{knee: float, a: float, b: float, sse: float} | nil
  def hinge_fit(points, opts \\ []) when is_list(points) do
    xs = points |> Enum.map(&elem(&1, 0)) |> Enum.uniq()

    if length(xs) < 3 do
      nil
    else
      step = Keyword.get(opts, :step, 0.5)
      {lo, hi} = Enum.min_max(xs)
      steps = trunc(Float.floor((hi - lo) / step))

      0..steps
      |> Enum.map(fn i -> hinge_at(points, lo + i * step) end)
      |> Enum.reduce(fn fit, best -> if fit.sse < best.sse - 1.0e-9, do: fit, else: best end)
      |> Map.new(fn {k, v} -> {k, Float.round(v * 1.0, 6)} end)
    end
  end

  defp hinge_at(points, knee) do
    hs = Enum.map(points, fn {x, _} -> max(0, x - knee) end)
    ys = Enum.map(points, &elem(&1, 1))
    mh = mean(hs)
    my = mean(ys)
    shh = hs |> Enum.map(&((&1 - mh) * (&1 - mh))) |> Enum.sum()
    shy = Enum.zip(hs, ys) |> Enum.map(fn {h, y} -> (h - mh) * (y - my) end) |> Enum.sum()
    b = if shh == 0, do: 0.0, else: shy / shh
    a = my - b * mh
    sse = Enum.zip(hs, ys) |> Enum.map(fn {h, y} -> :math.pow(y - a - b * h, 2) end) |> Enum.sum()
    %{knee: knee * 1.0, a: a, b: b, sse: sse}
  end

  defp sorted_percentile(sorted, q), do: Tartarus.Percentile.sorted(sorted, q)
end
