defmodule TartarusImmune.Sorting do
  @moduledoc """
  The sorting domain (thesis §6.5.1-6.5.2): which sorting algorithm to use for which kind of
  sequence.

  ## Features (each O(n log n) or better, normalized to 0..1)

  | feature | how | normalized by |
  |---|---|---|
  | length L | `length/1` | `min(L / 1000, 1)` (1000: the longest sequence of the data sets) |
  | inversions INV | merge-sort count, O(n log n) | `L (L - 1) / 2` (0 for L < 2) |
  | runs RUN | 1 + descents (maximal ascending runs), O(n) | `L` |
  | longest ascending subsequence LAS | patience sorting with a balanced tree, O(n log n) | `L` |

  (A sorted sequence: INV 0, RUN 1/L, LAS 1; reversed: INV 1, RUN 1, LAS 1/L.)

  ## Solutions

  `Quick`, `Insertion`, `Shell`, `Selection` (the thesis's four), plus `Merge` and `Heap`
  for on-the-fly addition (`TartarusImmune.Sorting.*`). Each sorts and counts key
  comparisons and moves of the textbook array algorithm. The cost (`score/2`) is
  comparisons + moves: deterministic. `score/3` with `measure: :time` gives microseconds
  instead (not deterministic, and not used: on P1 measured time ranks insertion and
  selection sort by how they are written for the BEAM, see `profile/2` and
  docs/immune.md). An iPkt's performance score divides the cost by `score_scale/1`,
  log2(L!): a property of the instance alone, so the score does not depend on which other
  algorithms ran beside it.

  ## Data sets (seeded)

    * `:p1` - all 40,320 permutations of 1..8 (index = lexicographic rank; the seed is
      not used);
    * `:p2` - 2,000 random permutations of length 1,000;
    * `:p3` - 2,000 nearly sorted sequences of length 1,000: 1..1000 with 20 random
      transpositions of elements at most 10 positions apart;
    * `:p4` - 2,000 random permutations of random length 8..1,000;
    * `:temp` - 2,000 readings series of a slowly varying temperature (§6.5.9), 100..1,000
      readings of 0.1 °C resolution (tenths as integers): a slow warming (0.2-0.4 °C per
      100 readings) plus a small random walk, so long stretches repeat a value or climb
      slowly.

  Instance `i` of a set is a function of `(seed, set, i)` only.
  """
  @behaviour TartarusImmune.Domain

  alias Tartarus.Clock
  alias TartarusImmune.Sorting.{Heap, Insertion, Merge, Quick, Selection, Shell}

  @solutions [Quick, Insertion, Shell, Selection, Merge, Heap]
  @sets %{p1: 40_320, p2: 2000, p3: 2000, p4: 2000, temp: 2000}
  @max_len 1000

  @impl true
  def name, do: "sorting"

  @impl true
  def feature_count, do: 4

  @impl true
  @doc "Every solution: Quick, Insertion, Shell, Selection, Merge, Heap."
  def solutions, do: @solutions

  @doc "The thesis's initial four (Quick, Insertion, Shell, Selection)."
  @spec base_solutions() :: [module()]
  def base_solutions, do: [Quick, Insertion, Shell, Selection]

  @impl true
  def solution_name(mod), do: mod.name()

  @impl true
  def sets, do: @sets

  # -- features ------------------------------------------------------------------------

  @impl true
  @doc """
  The normalized feature vector `[L, INV, RUN, LAS]`.

      iex> TartarusImmune.Sorting.features(Enum.to_list(1..10))
      [0.01, 0.0, 0.1, 1.0]
      iex> TartarusImmune.Sorting.features([4, 3, 2, 1])
      [0.004, 1.0, 1.0, 0.25]
  """
  def features([]), do: [0.0, 0.0, 0.0, 0.0]

  def features(list) do
    n = length(list)
    pairs = n * (n - 1) / 2

    [
      min(n / @max_len, 1.0),
      if(pairs > 0, do: inversions(list) / pairs, else: 0.0),
      runs(list) / n,
      las(list) / n
    ]
  end

  @doc """
  Inversions (pairs `i < j` with `a_i > a_j`), counted by merge sort in O(n log n).

      iex> TartarusImmune.Sorting.inversions([2, 4, 1, 3, 5])
      3
  """
  @spec inversions([number()]) :: non_neg_integer()
  def inversions(list), do: list |> inv(length(list)) |> elem(1)

  defp inv(l, n) when n < 2, do: {l, 0}

  defp inv(l, n) do
    h = div(n, 2)
    {a, b} = Enum.split(l, h)
    {a, ia} = inv(a, h)
    {b, ib} = inv(b, n - h)
    {m, im} = merge_count(a, h, b, [], 0)
    {m, ia + ib + im}
  end

  # la: how many are left in a; an element of b taken before them makes la inversions
  defp merge_count([], _la, b, acc, c), do: {Enum.reverse(acc, b), c}
  defp merge_count(a, _la, [], acc, c), do: {Enum.reverse(acc, a), c}

  defp merge_count([x | a], la, [y | _] = b, acc, c) when x <= y,
    do: merge_count(a, la - 1, b, [x | acc], c)

  defp merge_count(a, la, [y | b], acc, c), do: merge_count(a, la, b, [y | acc], c + la)

  @doc """
  Maximal ascending runs (1 + the number of descents `a_i > a_(i+1)`), O(n); 0 for `[]`.

      iex> TartarusImmune.Sorting.runs([1, 2, 5, 3, 4, 0])
      3
  """
  @spec runs([number()]) :: non_neg_integer()
  def runs([]), do: 0

  def runs([h | t]) do
    {_, r} = Enum.reduce(t, {h, 1}, fn x, {prev, r} -> {x, if(prev > x, do: r + 1, else: r)} end)
    r
  end

  @doc """
  Length of the longest strictly ascending subsequence, by patience sorting: the pile tops
  in a balanced tree (`:gb_sets`), each element replaces the smallest top >= it, or starts
  a pile. O(n log n).

      iex> TartarusImmune.Sorting.las([3, 1, 4, 1, 5, 9, 2, 6])
      4
  """
  @spec las([number()]) :: non_neg_integer()
  def las(list) do
    list
    |> Enum.reduce(:gb_sets.empty(), fn x, tops ->
      case :gb_sets.next(:gb_sets.iterator_from(x, tops)) do
        {top, _} -> tops |> then(&:gb_sets.delete(top, &1)) |> then(&:gb_sets.add(x, &1))
        :none -> :gb_sets.add(x, tops)
      end
    end)
    |> :gb_sets.size()
  end

  # -- solutions ----------------------------------------------------------------------

  @impl true
  @doc """
  The cost of `solution` on `instance`: comparisons + moves of a real run.

      iex> TartarusImmune.Sorting.score(TartarusImmune.Sorting.Insertion, [3, 1, 2])
      9
  """
  def score(solution, instance), do: score(solution, instance, [])

  @impl true
  @doc """
  The scale a cost is divided by in a performance score (`TartarusImmune.Domain`):
  `log2(L!)`, the information-theoretic least number of comparisons that sorts L distinct
  keys, at least 1. It depends on the length alone, so a score is "how many times the
  least possible" whatever else ran beside the solution, and a mean over sequences of
  different lengths (P4) is not dominated by the longest.

      iex> TartarusImmune.Sorting.score_scale(Enum.to_list(1..8)) |> Float.round(2)
      15.3
      iex> TartarusImmune.Sorting.score_scale([1])
      1.0
  """
  def score_scale(list) do
    n = length(list)
    Enum.reduce(2..max(n, 2)//1, 0.0, fn k, acc -> acc + :math.log2(k) end) |> max(1.0)
  end

  @doc """
  Like `score/2`; with `measure: :comparisons` the key comparisons alone (moves not
  counted: the cost of `TartarusImmune.Sorting.Comparisons`, a sensitivity option), with
  `measure: :time` the run's wall time in µs instead (the machine's,
  `Tartarus.Clock.machine_time/1`, in either clock mode; not deterministic). Raises if the
  output is not sorted.

      iex> TartarusImmune.Sorting.score(TartarusImmune.Sorting.Insertion, [3, 1, 2], measure: :comparisons)
      3
  """
  @spec score(module(), [number()], keyword()) :: number()
  def score(solution, instance, opts) do
    case Keyword.get(opts, :measure, :ops) do
      :ops ->
        {sorted, %{comparisons: c, moves: m}} = solution.sort(instance)
        check!(sorted, instance, solution)
        c + m

      :comparisons ->
        {sorted, %{comparisons: c}} = solution.sort(instance)
        check!(sorted, instance, solution)
        c

      :time ->
        {us, {sorted, _}} = machine_tc(fn -> solution.sort(instance) end)
        check!(sorted, instance, solution)
        us
    end
  end

  defp check!(sorted, instance, solution) do
    if length(sorted) != length(instance) or not ordered?(sorted),
      do: raise("#{inspect(solution)} did not sort")
  end

  defp ordered?([a, b | t]), do: a <= b and ordered?([b | t])
  defp ordered?(_), do: true

  @doc """
  A profile of `solutions` over the instances of `set` (seeded): for each solution's short
  name, `:mean_cost` (comparisons + moves), `:mean_score` (cost / `score_scale/1`, the
  performance score's default reference), `:mean_relative` (cost / the cheapest of
  `solutions` on the same instance, the `:best_candidate` reference), `:best_share` (the
  fraction of instances where it is the cheapest; ties go to every solution that ties) and,
  with `time: k`, `:median_ns`, the median over `k` timed passes of the wall time per sort
  of the instrumented algorithm on this BEAM (not deterministic).

  Options: `:solutions` (the base four), `:seed` (1), `:every` (take every n-th instance,
  1), `:time` (0: no timing).

      iex> prof = TartarusImmune.Sorting.profile(:p1, every: 997)
      iex> prof["IS"].mean_cost < prof["SelS"].mean_cost
      true
  """
  @spec profile(atom(), keyword()) :: %{String.t() => map()}
  def profile(set, opts \\ []) do
    sols = Keyword.get(opts, :solutions, base_solutions())
    seed = Keyword.get(opts, :seed, 1)
    every = Keyword.get(opts, :every, 1)
    insts = for i <- 0..(@sets[set] - 1)//every, do: instance(set, i, seed)
    n = length(insts)
    rows = for x <- insts, do: {x, Map.new(sols, &{&1, score(&1, x)})}

    Map.new(sols, fn sol ->
      stats = %{
        mean_cost: Enum.sum(Enum.map(rows, fn {_, c} -> c[sol] end)) / n,
        mean_score: Enum.sum(Enum.map(rows, fn {x, c} -> c[sol] / score_scale(x) end)) / n,
        mean_relative:
          Enum.sum(Enum.map(rows, fn {_, c} -> c[sol] / max(Enum.min(Map.values(c)), 1) end)) /
            n,
        best_share: Enum.count(rows, fn {_, c} -> c[sol] == Enum.min(Map.values(c)) end) / n
      }

      case Keyword.get(opts, :time, 0) do
        0 -> {sol.name(), stats}
        k -> {sol.name(), Map.put(stats, :median_ns, median_ns(sol, insts, k))}
      end
    end)
  end

  defp median_ns(sol, insts, k) do
    Enum.each(insts, &sol.sort/1)

    ts =
      for _ <- 1..k do
        {us, :ok} = machine_tc(fn -> Enum.each(insts, &sol.sort/1) end)
        us * 1000 / length(insts)
      end

    ts |> Enum.sort() |> Enum.at(div(k, 2))
  end

  # :timer.tc/1 on the machine's clock (a sort's cost on this BEAM, in µs, in either mode:
  # in virtual time a computation takes no time).
  defp machine_tc(fun) do
    t0 = Clock.machine_time()
    result = fun.()
    {System.convert_time_unit(Clock.machine_time() - t0, :native, :microsecond), result}
  end

  # -- data sets ------------------------------------------------------------------------

  @impl true
  @doc """
  Instance `i` of `set` under `seed` (see the moduledoc).

      iex> TartarusImmune.Sorting.instance(:p1, 0, 1)
      [1, 2, 3, 4, 5, 6, 7, 8]
      iex> TartarusImmune.Sorting.instance(:p1, 40_319, 1)
      [8, 7, 6, 5, 4, 3, 2, 1]
      iex> TartarusImmune.Sorting.instance(:p2, 5, 1) == TartarusImmune.Sorting.instance(:p2, 5, 1)
      true
  """
  def instance(:p1, i, _seed) when i in 0..40_319, do: unrank(Enum.to_list(1..8), i)

  def instance(:p2, i, seed) when i in 0..1999, do: shuffle(1..1000, rng(seed, 2, i))

  def instance(:p3, i, seed) when i in 0..1999 do
    {t, _} =
      Enum.reduce(1..20, {List.to_tuple(Enum.to_list(1..1000)), rng(seed, 3, i)}, fn _, {t, r} ->
        {a, r} = :rand.uniform_s(1000, r)
        {d, r} = :rand.uniform_s(10, r)
        b = if a + d <= 1000, do: a + d, else: a - d
        {t |> put_elem(a - 1, elem(t, b - 1)) |> put_elem(b - 1, elem(t, a - 1)), r}
      end)

    Tuple.to_list(t)
  end

  def instance(:p4, i, seed) when i in 0..1999 do
    {len, r} = :rand.uniform_s(993, rng(seed, 4, i))
    shuffle(1..(len + 7), r)
  end

  def instance(:temp, i, seed) when i in 0..1999 do
    r = rng(seed, 5, i)
    {len, r} = :rand.uniform_s(901, r)
    {base, r} = :rand.uniform_s(r)
    {slope, r} = :rand.uniform_s(r)

    {vals, _, _} =
      Enum.reduce(1..(len + 99), {[], 0.0, r}, fn k, {acc, walk, r} ->
        {z, r} = :rand.normal_s(r)
        walk = walk + 0.01 * z
        t = 18 + 6 * base + 0.002 * (1 + slope) * k + walk
        {[round(t * 10) | acc], walk, r}
      end)

    Enum.reverse(vals)
  end

  defp rng(seed, set, i), do: :rand.seed_s(:exsss, {seed, set * 1_000_003 + 7, i + 11})

  defp shuffle(range, r) do
    {pairs, _} =
      Enum.map_reduce(range, r, fn x, r ->
        {u, r} = :rand.uniform_s(r)
        {{u, x}, r}
      end)

    pairs |> Enum.sort() |> Enum.map(&elem(&1, 1))
  end

  defp unrank([], _i), do: []

  defp unrank(items, i) do
    f = Enum.reduce(1..(length(items) - 1)//1, 1, &(&1 * &2))
    {x, rest} = List.pop_at(items, div(i, f))
    [x | unrank(rest, rem(i, f))]
  end
end
