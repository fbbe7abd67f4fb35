defmodule Tartarus.TestSupportTest do
  # The shared test support: the polling helper's answers and failure, the tag vocabulary.
  use ExUnit.Case, async: true

  import Tartarus.TestSupport

  doctest Tartarus.TestSupport
  doctest Tartarus.TestSupport.Tags

  test "eventually returns the condition's first truthy value" do
    counter = :counters.new(1, [])

    assert eventually(fn ->
             :counters.add(counter, 1, 1)
             :counters.get(counter, 1) >= 3 && :third
           end) == :third
  end

  test "a condition that never holds fails the test with its code, the time waited and its last value" do
    error =
      assert_raise ExUnit.AssertionError, fn ->
        eventually(fn -> 1 + 1 == 3 end, 20)
      end

    assert error.message == "condition never held in 20 ms; its last value: false"
    assert Macro.to_string(error.expr) == "fn -> 1 + 1 == 3 end"
  end

  test "wait_for does not fail: it says it timed out, with the last value" do
    assert wait_for(fn -> nil end, 5) == {:timeout, nil}
    assert wait_for(fn -> [] end, 5) == {:ok, []}
  end

  test "an unknown TARTARUS_TESTS is refused with the valid levels" do
    assert_raise ArgumentError,
                 ~r/TARTARUS_TESTS must be one of all, default, quick, got: "slow"/,
                 fn ->
                   Tartarus.TestSupport.Tags.level("slow")
                 end
  end
end
