defmodule Tartarus.JSONTest do
  use ExUnit.Case, async: true

  alias Tartarus.JSON

  doctest Tartarus.JSON

  describe "encode!/2" do
    test "scalars" do
      assert JSON.encode!(nil) == "null"
      assert JSON.encode!(true) == "true"
      assert JSON.encode!(false) == "false"
      assert JSON.encode!(:ok) == ~s("ok")
      assert JSON.encode!(-12) == "-12"

      assert JSON.encode!(123_456_789_012_345_678_901_234_567_890) ==
               "123456789012345678901234567890"

      assert JSON.encode!(1.5) == "1.5"
      assert JSON.encode!(1.0e-10) == "1.0e-10"
      assert JSON.encode!(0.1) == "0.1"
    end

    test "escapes quotes, backslashes and every control character" do
      assert JSON.encode!(~s(a"b\\c)) == ~S("a\"b\\c")
      assert JSON.encode!("\n\r\t\b\f") == ~S("\n\r\t\b\f")
      assert JSON.encode!(<<0, 1, 0x1F>>) == ~S("\u0000\u0001\u001F")
      assert JSON.encode!("/ é 😀") == ~s("/ é 😀")
    end

    test "sorts keys and mixes atom and string keys" do
      assert JSON.encode!(%{"z" => 1, :a => 2, "m" => %{b: 1, a: 2}}) ==
               ~s({"a":2,"m":{"a":2,"b":1},"z":1})
    end

    test "dates and times become ISO 8601 strings" do
      assert JSON.encode!(~D[2018-05-01]) == ~s("2018-05-01")
      assert JSON.encode!(~U[2018-05-01 10:00:00Z]) == ~s("2018-05-01T10:00:00Z")
    end

    test "pretty output" do
      assert JSON.encode!([], pretty: true) == "[]"

      assert JSON.encode!(%{a: [%{}], b: 1}, pretty: true) == """
             {
               "a": [
                 {}
               ],
               "b": 1
             }\
             """
    end

    test "refuses what JSON cannot hold, saying what arrived" do
      for {term, text} <- [
            {{1, 2}, "cannot encode {1, 2}"},
            {self(), "cannot encode #PID"},
            {<<255>>, "expected valid UTF-8"},
            {%{1 => 2}, "cannot encode map key 1: expected an atom or a string"},
            {%{:a => 1, "a" => 2}, "both encode as \"a\""},
            {[1 | 2], "improper list"},
            {:nan, "expected a finite number"},
            {:infinity, "expected a finite number"},
            {MapSet.new(), "convert MapSet to a map first"}
          ] do
        error = assert_raise ArgumentError, fn -> JSON.encode!(term) end
        assert error.message =~ text
      end

      assert_raise ArgumentError, ~r/:pretty: expected a boolean, got: 1/, fn ->
        JSON.encode!(1, pretty: 1)
      end
    end

    test "encode_to_iodata!/2 gives the same bytes" do
      term = %{list: [1, "two", 3.0], nested: %{"k" => nil}}
      assert IO.iodata_to_binary(JSON.encode_to_iodata!(term)) == JSON.encode!(term)
    end
  end

  describe "decode/1" do
    test "values and whitespace" do
      assert JSON.decode(" \t\n\r[ 1 , -0 , 2.5e3 , -1E-2 , 1e2 , \"x\" ] ") ==
               {:ok, [1, 0, 2500.0, -0.01, 100.0, "x"]}

      assert JSON.decode("123456789012345678901234567890") ==
               {:ok, 123_456_789_012_345_678_901_234_567_890}

      assert JSON.decode(~s({"a":{"b":[]},"c":{}})) == {:ok, %{"a" => %{"b" => []}, "c" => %{}}}
      assert JSON.decode(~s({"a":1,"a":2})) == {:ok, %{"a" => 2}}
    end

    test "escapes" do
      assert JSON.decode(~S("\"\\\/\b\f\n\r\t")) == {:ok, "\"\\/\b\f\n\r\t"}
      assert JSON.decode(~S("\u0041\u00e9\u20AC")) == {:ok, "Aé€"}
      assert JSON.decode(~S("\ud83d\ude00")) == {:ok, "😀"}
      assert JSON.decode(~s("é😀")) == {:ok, "é😀"}
    end

    test "errors carry the byte position" do
      for {input, position} <- [
            {"", 0},
            {"   ", 3},
            {"[", 1},
            {"[1 2]", 3},
            {"{\"a\":1,}", 7},
            {"{a:1}", 1},
            {"01", 1},
            {"1.", 2},
            {"1e", 2},
            {"-", 1},
            {".5", 0},
            {"tru", 0},
            {"nul l", 0},
            {"\"abc", 4},
            {"\"a\nb\"", 2},
            {~S("\x"), 2},
            {~S("\u12G4"), 3},
            {~S("\ud83d"), 7},
            {~S("\ude00"), 1},
            {~S("\ud83d\u0041"), 7},
            {<<?", 255, ?">>, 1},
            {"[1] x", 4},
            {"1e400", 0},
            {"\"+\\u+123\"", 4}
          ] do
        assert JSON.decode(input) == {:error, {:invalid_json, position}},
               "input #{inspect(input)}: expected error at #{position}, got #{inspect(JSON.decode(input))}"
      end
    end

    test "decode!/1 raises with a readable message" do
      assert_raise JSON.DecodeError, "invalid JSON at byte 1: found end of input", fn ->
        JSON.decode!("[")
      end

      assert_raise JSON.DecodeError, "invalid JSON at byte 1: found byte 255", fn ->
        JSON.decode!(<<?", 255>>)
      end
    end
  end

  describe "round trip (PropEr)" do
    test "decode(encode(x)) == x for generated JSON values" do
      property =
        :proper.forall(json_gen(), fn raw ->
          try do
            term = to_term(raw)
            {:ok, back} = JSON.decode(JSON.encode!(term))
            {:ok, pretty_back} = JSON.decode(JSON.encode!(term, pretty: true))
            back === term and pretty_back === term
          rescue
            _ -> false
          end
        end)

      result = :proper.quickcheck(property, [:long_result, :quiet, {:numtests, 500}])
      assert result == true, "counterexample: #{inspect(result, charlists: :as_lists)}"
    end

    test "decode/1 never raises on arbitrary bytes or JSON-like garbage" do
      json_ish =
        :proper_types.list(:proper_types.elements(~c'{}[]:,"\\/ue0123456789.-+Eenulltrfas \n'))

      # Raw bytes, or a string over JSON's own alphabet (far more likely to get deep).
      garbage = :proper_types.oneof([:proper_types.binary(), json_ish])

      property =
        :proper.forall(garbage, fn input ->
          try do
            bin = if is_list(input), do: List.to_string(input), else: input

            match?({:ok, _}, JSON.decode(bin)) or
              match?({:error, {:invalid_json, p}} when p <= byte_size(bin), JSON.decode(bin))
          rescue
            _ -> false
          end
        end)

      result = :proper.quickcheck(property, [:long_result, :quiet, {:numtests, 500}])
      assert result == true, "counterexample: #{inspect(result, charlists: :as_lists)}"
    end
  end

  # PropEr 1.2 has no map or UTF-8 generators: generate a tagged tree and convert it.
  defp json_gen, do: :proper_types.sized(fn size -> json_gen(min(size, 12)) end)

  defp json_gen(0), do: leaf_gen()

  defp json_gen(size) do
    smaller = :proper_types.lazy(fn -> json_gen(div(size, 3)) end)

    :proper_types.frequency([
      {4, leaf_gen()},
      {1, {:list, :proper_types.list(smaller)}},
      {1, {:obj, :proper_types.list({string_gen(), smaller})}}
    ])
  end

  defp leaf_gen do
    :proper_types.oneof([
      :proper_types.integer(),
      :proper_types.largeint(),
      :proper_types.float(),
      :proper_types.boolean(),
      :null,
      {:str, string_gen()}
    ])
  end

  defp string_gen do
    :proper_types.list(
      :proper_types.frequency([
        {6, :proper_types.integer(0x20, 0x7E)},
        {2, :proper_types.integer(0, 0x1F)},
        {1, :proper_types.integer(0x80, 0xD7FF)},
        {1, :proper_types.integer(0xE000, 0xFFFD)},
        {1, :proper_types.integer(0x10000, 0x10FFFF)}
      ])
    )
  end

  defp to_term(:null), do: nil
  defp to_term({:str, chars}), do: List.to_string(chars)
  defp to_term({:list, items}), do: Enum.map(items, &to_term/1)

  defp to_term({:obj, pairs}),
    do: Map.new(pairs, fn {k, v} -> {List.to_string(k), to_term(v)} end)

  defp to_term(other), do: other
end
