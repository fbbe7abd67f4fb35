defmodule TartarusLats.JudgeTest do
  use ExUnit.Case, async: true
  doctest TartarusLats.Judge

  alias TartarusLats.Judge

  # In p1 from 10 to 50, in p2 from 50 to 100, then outside.
  @path [
    %{zone: :p1, entered_at: 10, left_at: 50},
    %{zone: :p2, entered_at: 50, left_at: 100}
  ]

  test "the lag window: true at some second of the 15 s before the release, no earlier" do
    assert Judge.lag_window() == 15
    assert Judge.correct?(:where_is, {:in_zone, :p1}, @path, 64)
    refute Judge.correct?(:where_is, {:in_zone, :p1}, @path, 65)
    # before the bearer came in, nothing is true of it
    refute Judge.correct?(:where_is, {:in_zone, :p1}, @path, 5)
    refute Judge.correct?(:where_is, :left_building, @path, 5)
  end

  test "an exit: left_building once outside, and for the 15 s after the exit the last zone too" do
    assert Judge.correct?(:where_am_i, :left_building, @path, 100)
    assert Judge.correct?(:where_am_i, {:in_zone, :p2}, @path, 110)
    refute Judge.correct?(:where_am_i, {:in_zone, :p2}, @path, 120)
    refute Judge.correct?(:where_am_i, :left_building, @path, 99)
  end

  test "in transit: right only once the bearer has left the zone" do
    assert Judge.correct?(:where_is, {:in_transit, :p1}, @path, 55)
    # still in p1 at the release: not in transit
    refute Judge.correct?(:where_is, {:in_transit, :p1}, @path, 40)
  end

  test "a Trace: the zones entered by some second of the window, and the status then" do
    trace = fn nodes, status ->
      {:ok, %{path: Enum.map(nodes, &%{node: &1, arrived_at: 0}), status: status}}
    end

    assert Judge.correct?(:trace, trace.([:p1, :p2], :present), @path, 60)
    # the tracker has not seen p2 yet: true of the bearer before 50, in the window
    assert Judge.correct?(:trace, trace.([:p1], :present), @path, 60)
    refute Judge.correct?(:trace, trace.([:p1], :present), @path, 70)
    assert Judge.correct?(:trace, trace.([:p1, :p2], :exited), @path, 105)
    refute Judge.correct?(:trace, trace.([:p1, :p2], :exited), @path, 90)
    # between two zones (left p1 at 50, p2 entered at 60)
    gap = [%{zone: :p1, entered_at: 10, left_at: 50}, %{zone: :p2, entered_at: 60, left_at: nil}]
    assert Judge.correct?(:trace, trace.([:p1], :in_transit), gap, 55)
    refute Judge.correct?(:trace, trace.([:p1], :in_transit), gap, 45)
    refute Judge.correct?(:trace, trace.([:p2, :p1], :present), @path, 60)
    refute Judge.correct?(:trace, :not_found, @path, 60)
    refute Judge.correct?(:trace, trace.([], :present), [], 60)
  end

  test "anything else is wrong" do
    refute Judge.correct?(:where_is, :not_found, @path, 60)
    refute Judge.correct?(:where_is, {:in_zone, :p3}, @path, 60)
    refute Judge.correct?(:where_is, {:error, :timeout}, @path, 60)
  end

  test "a Trace's time error: median distance of entry times, nil when the stays differ in number" do
    answer = fn times ->
      {:ok, %{path: Enum.map(times, &%{node: :p, arrived_at: &1}), status: :present}}
    end

    truth = %{path: @path}
    assert Judge.time_error(:trace, answer.([10, 50]), truth) == 0
    assert Judge.time_error(:trace, answer.([13, 54]), truth) in [3, 4]
    assert Judge.time_error(:trace, answer.([13]), truth) == nil
    assert Judge.time_error(:trace, :not_found, truth) == nil
  end
end
