defmodule Tartarus.PercentileTest do
  use ExUnit.Case, async: true

  doctest Tartarus.Percentile

  test "nearest rank: q = 0 is the smallest, q = 1 the largest, each an actual sample" do
    xs = Enum.shuffle(1..10)
    assert Tartarus.Percentile.of(xs, 0) == 1
    assert Tartarus.Percentile.of(xs, 1) == 10
    assert Tartarus.Percentile.of(xs, 0.9) == 9
    assert Tartarus.Percentile.of(xs, 0.91) == 10
  end
end
