defmodule TartarusTools.PropTest do
  use ExUnit.Case, async: true
  doctest TartarusTools.Prop

  alias TartarusTools.Prop

  test "a property that holds gives true" do
    property =
      :proper.forall(:proper_types.list(:proper_types.integer()), fn xs ->
        Prop.safely(fn -> Enum.reverse(Enum.reverse(xs)) == xs end)
      end)

    assert Prop.check(property, 100) == true
  end

  test "a property that fails, or raises, gives its shrunk counterexample" do
    property =
      :proper.forall(:proper_types.integer(), fn x ->
        Prop.safely(fn -> if x > 10, do: raise("too big"), else: true end)
      end)

    assert {:counterexample, [11]} = Prop.check(property, 500)
  end
end
