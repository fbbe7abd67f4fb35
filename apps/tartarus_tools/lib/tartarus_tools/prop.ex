defmodule TartarusTools.Prop do
  @moduledoc """
  PropEr properties from ExUnit: run one quietly, get `true` or the counterexample.

      property =
        :proper.forall(:proper_types.list(:proper_types.integer()), fn xs ->
          TartarusTools.Prop.safely(fn -> Enum.reverse(Enum.reverse(xs)) == xs end)
        end)

      assert TartarusTools.Prop.check(property, 300) == true

  PropEr (Debian's `erlang-proper`, installed by `scripts/test`) is needed when a property
  runs, not to compile this module. A property body that raises would abort the whole
  run: wrap it in `safely/1`, which turns an exception into a failing case (so PropEr
  shrinks it like any other).
  """

  @doc """
  Runs `property` for `numtests` cases. Returns `true`, or `{:counterexample, result}`
  with PropEr's long result (the shrunk counterexample).
  """
  @spec check(term(), pos_integer()) :: true | {:counterexample, term()}
  def check(property, numtests \\ 200) do
    # apply/3: PropEr is a test-time dependency, not a compile-time one.
    case apply(:proper, :quickcheck, [property, [:long_result, :quiet, {:numtests, numtests}]]) do
      true -> true
      other -> {:counterexample, other}
    end
  end

  @doc """
  Calls `fun`; an exception counts as `false` (a failing case).

      iex> TartarusTools.Prop.safely(fn -> raise "boom" end)
      false
      iex> TartarusTools.Prop.safely(fn -> 1 + 1 == 2 end)
      true
  """
  @spec safely((() -> boolean())) :: boolean()
  def safely(fun) do
    fun.()
  rescue
    _ -> false
  end
end
