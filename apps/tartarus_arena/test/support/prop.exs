defmodule TartarusArena.Prop do
  @moduledoc false
  # PropEr from ExUnit (DESIGN §9): run a property quietly, return true or
  # the counterexample. Property bodies must rescue and return false.

  @spec check(term(), pos_integer()) :: true | {:counterexample, term()}
  def check(property, numtests \\ 200) do
    case :proper.quickcheck(property, [:long_result, :quiet, {:numtests, numtests}]) do
      true -> true
      other -> {:counterexample, other}
    end
  end

  @spec safely((() -> boolean())) :: boolean()
  def safely(fun) do
    fun.()
  rescue
    _ -> false
  end
end
