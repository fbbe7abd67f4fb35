defmodule TartarusTools.StatsTest do
  use ExUnit.Case, async: true

  alias TartarusTools.Stats

  doctest Stats

  describe "quantiles" do
    test "nearest rank: every quantile is a sample, the lower middle for an even count" do
      xs = [10, 40, 20, 30]
      assert Stats.quantiles(xs, [0.0, 0.25, 0.5, 0.75, 1.0]) == [10, 10, 20, 30, 40]
      assert Stats.median(xs) == 20
    end

    test "the conventional median: the middle sample, or the mean of the two middle ones" do
      assert Stats.median_mid([13, 11]) == 12.0
      assert Stats.median_mid([10, 40, 20, 30]) == 25.0
      assert Stats.median_mid([5, 1, 9]) == 5
      # it lies between the nearest-rank quartiles, so a box drawn with it stays a box
      for n <- 1..12 do
        xs = for i <- 1..n, do: rem(i * 7919, 101)
        b = Stats.box(xs, median: :mid)
        assert b.q1 <= b.median and b.median <= b.q3
        assert b.median == Stats.describe(xs).median_mid
        assert Map.delete(b, :median) == Map.delete(Stats.box(xs), :median)
      end
    end

    test "box statistics: whiskers within 1.5 IQR, the rest are outliers" do
      s = Stats.box([10, -50, 11, 12, 13, 60])
      assert {s.q1, s.median, s.q3} == {10, 11, 13}
      assert {s.whisker_low, s.whisker_high} == {10, 13}
      assert s.outliers == [-50, 60]
      assert_raise ArgumentError, ~r/expected a list of numbers, got an element: "x"/, fn ->
        Stats.box([1, "x"])
      end

      s = Stats.box(Enum.to_list(1..9))
      assert {s.q1, s.median, s.q3} == {3, 5, 7}
      assert {s.whisker_low, s.whisker_high, s.outliers} == {1, 9, []}

      assert Stats.box([4]) == %{
               n: 1,
               min: 4,
               max: 4,
               q1: 4,
               median: 4,
               q3: 4,
               whisker_low: 4,
               whisker_high: 4,
               outliers: []
             }
    end

    test "describe drops nils and leaves an empty sample's statistics empty" do
      assert Stats.describe([nil, nil]) == %{
               n: 0,
               mean: nil,
               sd: nil,
               median: nil,
               median_mid: nil,
               q1: nil,
               q3: nil,
               iqr: nil,
               min: nil,
               max: nil
             }

      assert Stats.describe([7]).sd == nil
    end
  end

  describe "hinge_fit/2" do
    test "finds the knee of a noisy broken line and its slope" do
      pts =
        for {x, e} <- Enum.zip([5, 10, 15, 20, 25, 30, 35, 40, 50, 60], [1, -1, 0, 1, -1, 0, 1, -1, 0, 1]),
            do: {x, 200.0 + 4.0 * max(0, x - 30) + e}

      fit = Stats.hinge_fit(pts)
      assert_in_delta fit.knee, 30.0, 2.5
      assert_in_delta fit.b, 4.0, 0.3
      assert_in_delta fit.a, 200.0, 1.5
    end

    test "a flat series has no slope, whatever the knee" do
      fit = Stats.hinge_fit([{5, 3.0}, {10, 3.0}, {20, 3.0}])
      assert fit.b == 0.0 and fit.a == 3.0 and fit.sse == 0.0
    end

    test "a straight rising line puts the knee at the smallest x" do
      assert %{knee: 5.0, b: 2.0} = Stats.hinge_fit([{5, 10.0}, {10, 20.0}, {20, 40.0}])
    end
  end

  describe "mann_whitney/3" do
    test "complete separation of 10 against 10 has p = 1 / C(20, 10)" do
      r = Stats.mann_whitney(Enum.map(11..20, &(&1 / 1)), Enum.map(1..10, &(&1 / 1)))
      assert r.u == 100.0
      assert r.method == :exact
      assert_in_delta r.p_value, 1 / 184_756, 1.0e-12
    end

    test "identical samples are not significant; swapping the samples mirrors U" do
      xs = [0.0, 0.2, 0.5, 0.5, 1.0]
      assert Stats.mann_whitney(xs, xs).p_value > 0.5
      ys = [0.1, 0.0, 0.0, 0.3, 0.2]
      a = Stats.mann_whitney(xs, ys)
      b = Stats.mann_whitney(ys, xs)
      assert a.u + b.u == 25.0
      assert a.p_value < b.p_value
      less = Stats.mann_whitney(ys, xs, alternative: :less)
      assert less.p_value == a.p_value
      assert less.u == b.u
    end

    test "the exact p-value matches a brute-force enumeration of all splits (with ties)" do
      xs = [0.5, 0.0, 1.0, 0.5, 0.3]
      ys = [0.0, 0.0, 0.5, 0.1, 0.2, 0.0]
      pooled = xs ++ ys
      u = fn a, b -> Stats.mann_whitney(a, b).u end
      obs = u.(xs, ys)
      idx = Enum.to_list(0..(length(pooled) - 1))

      splits =
        for c <- combinations(idx, length(xs)) do
          a = Enum.map(c, &Enum.at(pooled, &1))
          b = Enum.map(idx -- c, &Enum.at(pooled, &1))
          u.(a, b) >= obs - 1.0e-9
        end

      brute = Enum.count(splits, & &1) / length(splits)
      assert_in_delta Stats.mann_whitney(xs, ys).p_value, brute, 1.0e-12
    end

    test "the normal approximation is close to the exact p at n = 20 a side" do
      xs = Enum.map(1..20, &rem(&1 * 7, 23))
      ys = Enum.map(1..20, &(rem(&1 * 5, 19) - 2))
      exact = Stats.mann_whitney(xs, ys, method: :exact)
      normal = Stats.mann_whitney(xs, ys, method: :normal)
      assert exact.u == normal.u
      assert_in_delta exact.p_value, normal.p_value, 0.01
    end

    test "40 a side, one-sided less: the normal approximation's known values" do
      # W = 190 pairs x > y plus 20 ties of 1/2 = 200; R's wilcox.test(1:40, 21:60,
      # alternative = "less", exact = FALSE) computes p = pnorm((200 - 800 + 0.5) / sigma),
      # sigma^2 = 1600 / 12 * (81 - 20 * 6 / (80 * 79)) (20 values tied in pairs) = 3.9785e-9
      r = Stats.mann_whitney(Enum.to_list(1..40), Enum.to_list(21..60), alternative: :less)
      assert {r.method, r.n1, r.n2, r.u} == {:normal, 40, 40, 200.0}
      assert_in_delta r.p_value, 3.978476281412657e-9, 1.0e-15

      # four tied blocks of 10 (rounds-like data): the tie-corrected variance
      # 1600 / 12 * (81 - sum(t^3 - t) / (80 * 79)), t = 10, 20, 20, 20, 10: p = 2.7866e-4
      xs = List.duplicate(10, 10) ++ List.duplicate(12, 10) ++ List.duplicate(14, 10) ++ List.duplicate(20, 10)
      ys = List.duplicate(12, 10) ++ List.duplicate(14, 10) ++ List.duplicate(20, 10) ++ List.duplicate(30, 10)
      r = Stats.mann_whitney(xs, ys, alternative: :less)
      assert r.u == 450.0
      assert_in_delta r.p_value, 2.786550200245078e-4, 1.0e-12
      assert Stats.mann_whitney(xs, ys).p_value > 0.99
    end

    test "empty samples give p = 1" do
      assert Stats.mann_whitney([], [1, 2]).p_value == 1.0
    end
  end

  defp combinations(_, 0), do: [[]]
  defp combinations([], _), do: []

  defp combinations([h | t], k),
    do: Enum.map(combinations(t, k - 1), &[h | &1]) ++ combinations(t, k)
end
