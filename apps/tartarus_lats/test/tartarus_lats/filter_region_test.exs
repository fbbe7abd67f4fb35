defmodule TartarusLats.FilterRegionTest do
  use ExUnit.Case, async: true
  doctest TartarusLats.RSSIFilter
  doctest TartarusLats.Region

  alias TartarusLats.{Region, RSSIFilter}

  test "default window is 6 and the average is over the last 6 samples" do
    f = RSSIFilter.new()
    assert f.window == 6

    {avgs, _} = Enum.map_reduce([-60, -60, -60, -60, -60, -60, -90], f, &RSSIFilter.push(&2, &1))
    assert Enum.take(avgs, 6) == List.duplicate(-60.0, 6)
    assert List.last(avgs) == -65.0
  end

  test "configurable window" do
    f = RSSIFilter.new(window: 1)
    {_, f} = RSSIFilter.push(f, -50)
    assert {-70.0, _} = RSSIFilter.push(f, -70)
  end

  test "calibration from the path-loss model and explicit thresholds" do
    cal = Region.calibrate(tx_power: -59, exponent: 3.0)
    assert_in_delta cal.near_dbm, -59 - 30 * :math.log10(2), 1.0e-9
    assert_in_delta cal.far_dbm, -59 - 30 * :math.log10(5), 1.0e-9
    assert_raise ArgumentError, ~r/near_dbm > far_dbm/, fn -> Region.calibration(-80, -70) end
    assert_raise ArgumentError, ~r/:exponent/, fn -> Region.calibrate(exponent: 0) end
  end
end
