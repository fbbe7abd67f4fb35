defmodule Tartarus.OptionsTest do
  use ExUnit.Case, async: true

  alias Tartarus.Options

  doctest Options
  doctest Tartarus.Options.Platform

  @where "f/1"

  defp check(type, value), do: Options.validate([k: value], [k: [type: type]], @where)

  test "defaults fill in; keys keep the schema's order" do
    schema = [a: [type: :integer, default: 1], b: [type: :atom], c: [type: :any, default: nil]]
    assert Options.validate([], schema, @where) == {:ok, [a: 1, c: nil]}
    assert Options.validate([c: 3, b: :x], schema, @where) == {:ok, [a: 1, b: :x, c: 3]}
  end

  test "required options" do
    schema = [a: [type: :integer, required: true]]
    assert Options.validate([], schema, @where) == {:error, "required option :a not given to f/1"}
    assert Options.validate([a: 1], schema, @where) == {:ok, [a: 1]}
  end

  test "unknown keys and non-keyword options" do
    schema = [a: [type: :any], b: [type: :any]]

    assert Options.validate([c: 1], schema, @where) ==
             {:error, "invalid options given to f/1: unknown key :c, known keys: [:a, :b]"}

    assert Options.validate([1, 2], schema, @where) ==
             {:error, "invalid options given to f/1: expected a keyword list, got: [1, 2]"}

    assert Options.validate(%{a: 1}, schema, @where) ==
             {:error, "invalid options given to f/1: expected a keyword list, got: %{a: 1}"}
  end

  test "every type accepts what it should and names what it expected" do
    cases = [
      {:any, [nil, 1, "x"], [], "any term"},
      {:atom, [:a, nil, true], [1, "a"], "an atom"},
      {:boolean, [true, false], [nil, 1], "a boolean"},
      {:integer, [-1, 0, 5], [1.0, "1"], "an integer"},
      {:pos_integer, [1, 9], [0, -1, 1.5], "a positive integer"},
      {:non_neg_integer, [0, 9], [-1, 0.5], "a non-negative integer"},
      {:number, [1, 1.5, -2], [:a, "1"], "a number"},
      {:probability, [0, 0.5, 1, 1.0], [-0.1, 1.01, :a], "a number between 0 and 1"},
      {:timeout, [0, 10, :infinity], [-1, :never], "a non-negative integer or :infinity"},
      {:pos_integer_or_infinity, [1, :infinity], [0, :never], "a positive integer or :infinity"},
      {:string, ["", "x"], [:x, ~c"x"], "a string"},
      {:keyword, [[], [a: 1]], [[1], %{}], "a keyword list"},
      {:host, [:a, "a", {:a, :n@h}], [3, nil, {:a, "n"}], "a host (a name, or {name, node})"},
      {{:list, :host}, [[], [:a, {:b, :n@h}]], [:a, [3]],
       "a list of hosts (names, or {name, node})"},
      {{:list, :integer}, [[], [1, 2]], [[1, :a], 1], "a list of an integer"},
      {{:in, [:x, :y]}, [:x, :y], [:z], "one of [:x, :y]"},
      {{:fun, 1}, [&Function.identity/1], [&Enum.map/2, :f], "a function of arity 1"}
    ]

    for {type, goods, bads, expected} <- cases do
      for good <- goods,
          do: assert(check(type, good) == {:ok, [k: good]}, "#{inspect(type)} #{inspect(good)}")

      for bad <- bads do
        assert check(type, bad) ==
                 {:error,
                  "invalid options given to f/1 for key :k: expected #{expected}, got: #{inspect(bad)}"}
      end
    end
  end

  test "a key without a type accepts anything" do
    assert Options.validate([k: 1], [k: [doc: "x"]], @where) == {:ok, [k: 1]}
  end

  test "validate!/3 raises ArgumentError with the message" do
    schema = [n: [type: :pos_integer]]
    assert Options.validate!([n: 1], schema, @where) == [n: 1]

    assert_raise ArgumentError,
                 "invalid options given to f/1 for key :n: expected a positive integer, got: 0",
                 fn ->
                   Options.validate!([n: 0], schema, @where)
                 end
  end

  test "docs/1 renders one line per key with its doc, requirement and default" do
    schema = [
      hops: [type: :pos_integer, default: 10, doc: "number of hops"],
      name: [type: :string, required: true, doc: "a name"]
    ]

    assert [hops, name] = String.split(Options.docs(schema), "\n")
    assert hops =~ ~r/^  \* `:hops` - number of hops.*Defaults to `10`\.$/
    assert name =~ ~r/^  \* `:name` - a name.*Required\.$/
  end

  test "docs/1 separates the doc from what follows" do
    # Options.docs/1 appends " Defaults to ..." / " Required." straight after the doc text,
    # so the generated docs read "number of hops Defaults to `10`.".
    schema = [
      hops: [type: :pos_integer, default: 10, doc: "number of hops"],
      name: [type: :string, required: true, doc: "a name"]
    ]

    assert Options.docs(schema) ==
             "  * `:hops` - number of hops. Defaults to `10`.\n  * `:name` - a name. Required."
  end

  describe "nested schemas, tuples and alternatives" do
    @limits [
      max: [type: :pos_integer, default: 5, doc: "a limit"],
      rate: [
        type: {:or, [{:tuple, [:pos_integer, :pos_integer]}, {:in, [:infinity]}]},
        expected: "{count, ms} or :infinity",
        default: :infinity
      ]
    ]
    @outer [limits: [type: {:keyword, @limits}, default: [], doc: "the limits"]]

    test "a nested keyword list gets its defaults, given or not" do
      assert Options.validate([], @outer, @where) == {:ok, [limits: [max: 5, rate: :infinity]]}

      assert Options.validate([limits: [rate: {1, 2}]], @outer, @where) ==
               {:ok, [limits: [max: 5, rate: {1, 2}]]}

      assert Options.defaults(@outer) == [limits: [max: 5, rate: :infinity]]
    end

    test "errors name the key path, and :expected replaces the type's words" do
      assert Options.validate([limits: [max: 0]], @outer, @where) ==
               {:error,
                "invalid options given to f/1 for key [:limits, :max]: expected a positive integer, got: 0"}

      assert Options.validate([limits: [rate: {1, 0}]], @outer, @where) ==
               {:error,
                "invalid options given to f/1 for key [:limits, :rate]: expected {count, ms} or :infinity, got: {1, 0}"}

      assert Options.validate([limits: [bogus: 1]], @outer, @where) ==
               {:error,
                "invalid options given to f/1 for key :limits: unknown key :bogus, known keys: [:max, :rate]"}

      assert Options.validate([limits: 3], @outer, @where) ==
               {:error,
                "invalid options given to f/1 for key :limits: expected a keyword list, got: 3"}
    end

    test "tuples, alternatives and maps" do
      assert check({:tuple, [:atom, :integer]}, {:a, 1}) == {:ok, [k: {:a, 1}]}

      assert check({:tuple, [:atom, :integer]}, {:a, 1, 2}) ==
               {:error,
                "invalid options given to f/1 for key :k: expected a tuple {an atom, an integer}, got: {:a, 1, 2}"}

      assert check({:or, [:integer, :string]}, "x") == {:ok, [k: "x"]}

      assert check({:or, [:integer, :string]}, :x) ==
               {:error,
                "invalid options given to f/1 for key :k: expected an integer or a string, got: :x"}

      assert check(:map, %{}) == {:ok, [k: %{}]}
      assert {:error, _} = check(:map, [])

      assert check({:struct, MapSet}, MapSet.new()) == {:ok, [k: MapSet.new()]}

      assert check({:struct, MapSet}, %{}) ==
               {:error, "invalid options given to f/1 for key :k: expected a %MapSet{}, got: %{}"}

      even = [
        k: [type: {:custom, &(is_integer(&1) and rem(&1, 2) == 0)}, expected: "an even integer"]
      ]

      assert Options.validate([k: 4], even, @where) == {:ok, [k: 4]}

      assert Options.validate([k: 3], even, @where) ==
               {:error,
                "invalid options given to f/1 for key :k: expected an even integer, got: 3"}
    end

    test "docs/1 lists a nested schema's keys under its key" do
      assert Options.docs(@outer) ==
               "  * `:limits` - the limits. Defaults to `[]`.\n" <>
                 "      * `:max` - a limit. Defaults to `5`.\n" <>
                 "      * `:rate` Defaults to `:infinity`."
    end
  end
end
