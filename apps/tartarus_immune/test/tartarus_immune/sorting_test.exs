defmodule TartarusImmune.SortingTest do
  use ExUnit.Case, async: true
  alias TartarusImmune.{Domain, Sorting}
  alias TartarusTools.Prop
  import :proper_types, only: [list: 1, integer: 2]
  doctest TartarusImmune.Sorting
  doctest TartarusImmune.Sorting.Insertion
  doctest TartarusImmune.Sorting.Selection
  doctest TartarusImmune.Sorting.Shell
  doctest TartarusImmune.Sorting.Quick
  doctest TartarusImmune.Sorting.Merge
  doctest TartarusImmune.Sorting.Heap
  doctest TartarusImmune.Domain

  # brute-force O(n^2) versions
  defp inv_bf(l) do
    t = List.to_tuple(l)
    n = tuple_size(t)

    for i <- 0..(n - 1)//1,
        j <- (i + 1)..(n - 1)//1,
        elem(t, i) > elem(t, j),
        reduce: 0,
        do: (c -> c + 1)
  end

  defp runs_bf([]), do: 0

  defp runs_bf(l),
    do: 1 + Enum.count(0..(length(l) - 2)//1, &(Enum.at(l, &1) > Enum.at(l, &1 + 1)))

  defp las_bf([]), do: 0

  defp las_bf(l) do
    t = List.to_tuple(l)
    n = tuple_size(t)

    best =
      Enum.reduce(0..(n - 1), %{}, fn j, best ->
        b =
          Enum.reduce(0..(j - 1)//1, 1, fn i, b ->
            if elem(t, i) < elem(t, j), do: max(b, best[i] + 1), else: b
          end)

        Map.put(best, j, b)
      end)

    best |> Map.values() |> Enum.max()
  end

  test "PropEr: features agree with brute-force O(n^2) versions (duplicates included)" do
    prop =
      :proper.forall(list(integer(-20, 20)), fn l ->
        Prop.safely(fn ->
          Sorting.inversions(l) == inv_bf(l) and Sorting.runs(l) == runs_bf(l) and
            Sorting.las(l) == las_bf(l)
        end)
      end)

    assert Prop.check(prop, 300) == true
  end

  test "PropEr: every algorithm sorts, and costs are deterministic" do
    prop =
      :proper.forall(list(integer(-50, 50)), fn l ->
        Prop.safely(fn ->
          Enum.all?(Sorting.solutions(), fn s ->
            {sorted, %{comparisons: c, moves: m}} = s.sort(l)

            sorted == Enum.sort(l) and c >= 0 and m >= 0 and
              s.sort(l) == {sorted, %{comparisons: c, moves: m}}
          end)
        end)
      end)

    assert Prop.check(prop, 300) == true
  end

  test "features are normalized and fit the extremes" do
    assert Sorting.features(Enum.to_list(1..1000)) == [1.0, 0.0, 0.001, 1.0]
    assert Sorting.features(Enum.to_list(1000..1)) == [1.0, 1.0, 1.0, 0.001]

    for set <- [:p1, :p2, :p3, :p4, :temp], i <- [0, 7, 1999] do
      fv = Sorting.features(Sorting.instance(set, i, 3))
      assert length(fv) == 4 and Enum.all?(fv, &(&1 >= 0 and &1 <= 1))
    end
  end

  test "data sets: sizes, shapes, seeded" do
    assert Sorting.sets().p1 == 40_320
    p1 = for i <- 0..40_319//97, do: Sorting.instance(:p1, i, 1)
    assert Enum.all?(p1, &(Enum.sort(&1) == Enum.to_list(1..8)))
    assert length(Enum.uniq(p1)) == length(p1)
    assert Enum.sort(Sorting.instance(:p2, 1, 1)) == Enum.to_list(1..1000)
    assert Sorting.instance(:p2, 1, 1) != Sorting.instance(:p2, 1, 2)
    p3 = Sorting.instance(:p3, 1, 1)
    assert length(p3) == 1000 and Sorting.inversions(p3) < 500
    assert length(Sorting.instance(:p4, 9, 1)) in 8..1000
  end

  test "the oracle and the class bests of §6.5.2 (IS, QS, IS, QS) on 20 instances each" do
    sols = Sorting.base_solutions()

    for {set, want} <- [p1: "IS", p2: "QS", p3: "IS", p4: "QS"] do
      refs = for i <- 0..19, do: {set, i * 97}
      {best, _} = Domain.class_best(Sorting, sols, refs, 1)
      assert best.name() == want, "#{set}"
    end

    {best, costs} = Domain.oracle(Sorting, sols, Enum.to_list(1..1000))
    assert best == Sorting.Insertion and costs[Sorting.Insertion] == 999 + 2 * 999
  end

  describe "the performance score ζ of an interaction (Node.interact/4)" do
    alias TartarusImmune.{Node, Params}
    alias Sorting.{Insertion, Selection}

    setup do
      # a P1 permutation on which insertion sort is cheaper than selection sort
      inst = Sorting.instance(:p1, 100, 1)
      assert Sorting.score(Insertion, inst) < Sorting.score(Selection, inst)
      fx = Sorting.features(inst)
      m = fn id, sol -> {id, %{sol: sol, fv: fx, tau: 10.0, zeta: nil, n: 0}} end
      score = &Sorting.score(&1, inst)
      p = Params.new!() |> Map.merge(%{q_current: 2, scale: Sorting.score_scale(inst)})

      %{
        inst: inst,
        fx: fx,
        alone: [m.(1, Selection)],
        pair: [m.(1, Selection), m.(2, Insertion)],
        score: score,
        p: p
      }
    end

    test "with score_ref: :instance it is the solution's own, whoever else ran", c do
      own = {Sorting.score(Selection, c.inst) / Sorting.score_scale(c.inst), 1}
      assert Node.interact(c.alone, c.fx, c.score, c.p).scores[1] == own
      assert Node.interact(c.pair, c.fx, c.score, c.p).scores[1] == own
    end

    test "with score_ref: :best_candidate a solution alone scores the perfect 1.0", c do
      p = %{c.p | score_ref: :best_candidate}
      assert Node.interact(c.alone, c.fx, c.score, p).scores[1] == {1.0, 1}
      {worse, 1} = Node.interact(c.pair, c.fx, c.score, p).scores[1]
      assert worse > 1.0
    end
  end

  test "P1 (every 97th permutation): by the mean score of either reference IS ranks before SelS" do
    insts = for i <- 0..40_319//97, do: Sorting.instance(:p1, i, 1)
    sols = [Sorting.Insertion, Sorting.Selection]

    mean = fn f ->
      Map.new(sols, fn s -> {s, Enum.sum(Enum.map(insts, &f.(s, &1))) / length(insts)} end)
    end

    own = mean.(fn s, i -> Sorting.score(s, i) / Sorting.score_scale(i) end)

    rel =
      mean.(fn s, i -> Sorting.score(s, i) / Enum.min(Enum.map(sols, &Sorting.score(&1, i))) end)

    assert own[Sorting.Insertion] < own[Sorting.Selection]
    assert rel[Sorting.Insertion] < rel[Sorting.Selection]
  end
end
