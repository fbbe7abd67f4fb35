defmodule TartarusImmune.Evolution.StatsTest do
  use ExUnit.Case, async: true

  alias TartarusImmune.Evolution.Stats

  doctest Stats

  test "complete separation of 10 against 10 has p = 1 / C(20, 10)" do
    r = Stats.mann_whitney(Enum.map(11..20, &(&1 / 1)), Enum.map(1..10, &(&1 / 1)))
    assert r.u == 100.0
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

  defp combinations(_, 0), do: [[]]
  defp combinations([], _), do: []

  defp combinations([h | t], k),
    do: Enum.map(combinations(t, k - 1), &[h | &1]) ++ combinations(t, k)
end
