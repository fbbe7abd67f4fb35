defmodule TartarusImmune.Sorting.Insertion do
  @moduledoc """
  Insertion sort, instrumented: `sort/1` returns the sorted list and the counts of the
  textbook array algorithm (comparisons of keys; moves: every shift, plus the key's save and
  store on each pass). Runs in O(n + inversions) on a list (the sorted prefix is kept
  reversed), counting exactly what the array version counts.

      iex> TartarusImmune.Sorting.Insertion.sort([3, 1, 2])
      {[1, 2, 3], %{comparisons: 3, moves: 6}}
  """
  @doc "The short name."
  def name, do: "IS"

  @doc "Sorts `list`; returns `{sorted, %{comparisons:, moves:}}`."
  @spec sort([number()]) ::
          {[number()], %{comparisons: non_neg_integer(), moves: non_neg_integer()}}
  def sort([]), do: {[], %{comparisons: 0, moves: 0}}

  def sort([h | t]) do
    {rev, c, m} =
      Enum.reduce(t, {[h], 0, 0}, fn x, {acc, c, m} ->
        {acc, dc, shifts} = ins(x, acc)
        {acc, c + dc, m + shifts + 2}
      end)

    {Enum.reverse(rev), %{comparisons: c, moves: m}}
  end

  # acc is the sorted prefix, largest first. Returns {acc', comparisons, shifts}.
  @doc false
  def ins(x, [y | rest]) when y > x do
    {l, c, s} = ins(x, rest)
    {[y | l], c + 1, s + 1}
  end

  def ins(x, [_ | _] = l), do: {[x | l], 1, 0}
  def ins(x, []), do: {[x], 0, 0}
end

defmodule TartarusImmune.Sorting.Selection do
  @moduledoc """
  Selection sort, instrumented: the textbook array algorithm (Sedgewick & Wayne's
  Algorithm 2.1, CLRS Exercise 2.2-2): for each position but the last, the minimum of the
  rest, found with `len - 1` comparisons, is exchanged with the element there (3 moves per
  exchange, made unconditionally as the textbook does).

      iex> TartarusImmune.Sorting.Selection.sort([3, 1, 2])
      {[1, 2, 3], %{comparisons: 3, moves: 6}}
  """
  @doc "The short name."
  def name, do: "SelS"

  @doc "Sorts `list`; returns `{sorted, %{comparisons:, moves:}}`."
  @spec sort([number()]) ::
          {[number()], %{comparisons: non_neg_integer(), moves: non_neg_integer()}}
  def sort(list), do: go(list, [], 0, 0)

  defp go([], acc, c, m), do: {Enum.reverse(acc), %{comparisons: c, moves: m}}
  defp go([x], acc, c, m), do: go([], [x | acc], c, m)

  defp go([h | t], acc, c, m) do
    {min, k} = min_index(t, h, 0, 1)
    c = c + length(t)

    if k == 0 do
      go(t, [h | acc], c, m + 3)
    else
      # the array swap: the head takes the minimum's place in the rest
      go(List.replace_at(t, k - 1, h), [min | acc], c, m + 3)
    end
  end

  defp min_index([], min, k, _i), do: {min, k}
  defp min_index([x | t], min, _k, i) when x < min, do: min_index(t, x, i, i + 1)
  defp min_index([_ | t], min, k, i), do: min_index(t, min, k, i + 1)
end

defmodule TartarusImmune.Sorting.Shell do
  @moduledoc """
  Shell sort with Shell's original gaps (n/2, n/4, ..., 1), instrumented like insertion
  sort (each gap's pass is an insertion sort of every interleaved subsequence).

      iex> TartarusImmune.Sorting.Shell.sort([4, 3, 2, 1])
      {[1, 2, 3, 4], %{comparisons: 6, moves: 14}}
  """
  alias TartarusImmune.Sorting.Insertion

  @doc "The short name."
  def name, do: "ShS"

  @doc "Sorts `list`; returns `{sorted, %{comparisons:, moves:}}`."
  @spec sort([number()]) ::
          {[number()], %{comparisons: non_neg_integer(), moves: non_neg_integer()}}
  def sort(list) do
    n = length(list)
    gaps = Stream.iterate(div(n, 2), &div(&1, 2)) |> Enum.take_while(&(&1 > 0))

    {list, c, m} =
      Enum.reduce(gaps, {list, 0, 0}, fn h, {l, c, m} ->
        t = List.to_tuple(l)

        {pairs, c, m} =
          Enum.reduce(0..(h - 1), {[], c, m}, fn r, {pairs, c, m} ->
            idx = Enum.take_every(r..(n - 1), h)
            {sorted, %{comparisons: dc, moves: dm}} = Insertion.sort(Enum.map(idx, &elem(t, &1)))
            {Enum.zip(idx, sorted) ++ pairs, c + dc, m + dm}
          end)

        {pairs |> List.keysort(0) |> Enum.map(&elem(&1, 1)), c, m}
      end)

    {list, %{comparisons: c, moves: m}}
  end
end

defmodule TartarusImmune.Sorting.Quick do
  @moduledoc """
  Quicksort with Hoare's partition and the middle element as pivot, on an `:array`,
  instrumented (every key comparison of the two scans; 3 moves per swap).

      iex> TartarusImmune.Sorting.Quick.sort([3, 1, 2])
      {[1, 2, 3], %{comparisons: 9, moves: 6}}
  """
  @doc "The short name."
  def name, do: "QS"

  @doc "Sorts `list`; returns `{sorted, %{comparisons:, moves:}}`."
  @spec sort([number()]) ::
          {[number()], %{comparisons: non_neg_integer(), moves: non_neg_integer()}}
  def sort(list) do
    a = :array.from_list(list)
    {a, c, m} = qs(a, 0, length(list) - 1, 0, 0)
    {:array.to_list(a), %{comparisons: c, moves: m}}
  end

  defp qs(a, lo, hi, c, m) when lo < hi do
    pivot = :array.get(div(lo + hi, 2), a)
    {p, a, c, m} = partition(a, lo - 1, hi + 1, pivot, c, m)
    {a, c, m} = qs(a, lo, p, c, m)
    qs(a, p + 1, hi, c, m)
  end

  defp qs(a, _lo, _hi, c, m), do: {a, c, m}

  defp partition(a, i, j, pivot, c, m) do
    {i, c} = up(a, i + 1, pivot, c)
    {j, c} = down(a, j - 1, pivot, c)

    if i >= j do
      {j, a, c, m}
    else
      x = :array.get(i, a)
      a = :array.set(i, :array.get(j, a), a) |> then(&:array.set(j, x, &1))
      partition(a, i, j, pivot, c, m + 3)
    end
  end

  defp up(a, i, pivot, c) do
    if :array.get(i, a) < pivot, do: up(a, i + 1, pivot, c + 1), else: {i, c + 1}
  end

  defp down(a, j, pivot, c) do
    if :array.get(j, a) > pivot, do: down(a, j - 1, pivot, c + 1), else: {j, c + 1}
  end
end

defmodule TartarusImmune.Sorting.Merge do
  @moduledoc """
  Top-down merge sort, instrumented (comparisons of the merges; moves: every element copied
  to the auxiliary array and back, 2 per element per merge).

      iex> TartarusImmune.Sorting.Merge.sort([3, 1, 2])
      {[1, 2, 3], %{comparisons: 3, moves: 10}}
  """
  @doc "The short name."
  def name, do: "MS"

  @doc "Sorts `list`; returns `{sorted, %{comparisons:, moves:}}`."
  @spec sort([number()]) ::
          {[number()], %{comparisons: non_neg_integer(), moves: non_neg_integer()}}
  def sort(list) do
    {l, c, m} = ms(list, length(list))
    {l, %{comparisons: c, moves: m}}
  end

  defp ms(l, n) when n < 2, do: {l, 0, 0}

  defp ms(l, n) do
    h = div(n, 2)
    {a, b} = Enum.split(l, h)
    {a, ca, ma} = ms(a, h)
    {b, cb, mb} = ms(b, n - h)
    {merged, cm} = merge(a, b, [], 0)
    {merged, ca + cb + cm, ma + mb + 2 * n}
  end

  defp merge([], b, acc, c), do: {Enum.reverse(acc, b), c}
  defp merge(a, [], acc, c), do: {Enum.reverse(acc, a), c}
  defp merge([x | a], [y | _] = b, acc, c) when x <= y, do: merge(a, b, [x | acc], c + 1)
  defp merge(a, [y | b], acc, c), do: merge(a, b, [y | acc], c + 1)
end

defmodule TartarusImmune.Sorting.Heap do
  @moduledoc """
  Heap sort (build a max-heap bottom-up, then sift down), on an `:array`, instrumented
  (key comparisons; 3 moves per swap).

      iex> {sorted, _} = TartarusImmune.Sorting.Heap.sort([3, 1, 2])
      iex> sorted
      [1, 2, 3]
  """
  @doc "The short name."
  def name, do: "HS"

  @doc "Sorts `list`; returns `{sorted, %{comparisons:, moves:}}`."
  @spec sort([number()]) ::
          {[number()], %{comparisons: non_neg_integer(), moves: non_neg_integer()}}
  def sort(list) do
    n = length(list)
    a = :array.from_list(list)

    {a, c, m} =
      Enum.reduce((div(n, 2) - 1)..0//-1, {a, 0, 0}, fn i, {a, c, m} -> sift(a, i, n, c, m) end)

    {a, c, m} =
      Enum.reduce((n - 1)..1//-1, {a, c, m}, fn last, {a, c, m} ->
        a = swap(a, 0, last)
        sift(a, 0, last, c, m + 3)
      end)

    {:array.to_list(a), %{comparisons: c, moves: m}}
  end

  defp sift(a, i, n, c, m) do
    l = 2 * i + 1
    r = l + 1

    cond do
      l >= n ->
        {a, c, m}

      true ->
        {big, c} =
          if r < n do
            if :array.get(r, a) > :array.get(l, a), do: {r, c + 1}, else: {l, c + 1}
          else
            {l, c}
          end

        if :array.get(big, a) > :array.get(i, a) do
          sift(swap(a, i, big), big, n, c + 1, m + 3)
        else
          {a, c + 1, m}
        end
    end
  end

  defp swap(a, i, j) do
    x = :array.get(i, a)
    a |> then(&:array.set(i, :array.get(j, &1), &1)) |> then(&:array.set(j, x, &1))
  end
end
