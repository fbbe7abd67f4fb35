defmodule Tartarus.EnvelopeTest do
  use ExUnit.Case, async: true

  alias Tartarus.Envelope

  doctest Envelope

  test "new_id/0 gives distinct lowercase hex ids of 16 characters" do
    ids = for _ <- 1..1000, do: Envelope.new_id()
    assert length(Enum.uniq(ids)) == 1000
    assert Enum.all?(ids, &(&1 =~ ~r/\A[0-9a-f]{16}\z/))
  end

  test "seed_rng/1 is deterministic per seed and exported" do
    assert Envelope.seed_rng(:a) == Envelope.seed_rng(:a)
    assert Envelope.seed_rng(:a) != Envelope.seed_rng(:b)
    assert Envelope.seed_rng({:any, "term", 1}) == Envelope.seed_rng({:any, "term", 1})
    state = :rand.seed_s(Envelope.seed_rng(:a))
    {x, _} = :rand.uniform_s(state)
    {y, _} = :rand.uniform_s(:rand.seed_s(Envelope.seed_rng(:a)))
    assert x == y
  end

  test "modules/1: the agent's module, its ships, its payload modules, once each" do
    env = %Envelope{id: "x", module: M, ships: [A, B], payload: %{data: %{}, modules: [B, C]}}
    assert Envelope.modules(env) == [M, A, B, C]
    assert Envelope.modules(%Envelope{id: "x", module: M}) == [M]
  end

  test "defaults" do
    env = %Envelope{id: "x", module: M}
    assert env.hops == 0
    assert env.ttl == :infinity
    assert env.static == false
    assert env.payload == %{data: %{}, modules: []}
    assert env.visits == %{}
  end

  describe "portable?/1" do
    test "funs in map keys, improper list tails and deep tuples are found" do
      f = fn -> 1 end
      assert {:error, {:not_portable, :fun, _}} = Envelope.portable?(%{f => 1})
      assert {:error, {:not_portable, :fun, [1]}} = Envelope.portable?([1 | f])
      assert {:error, {:not_portable, :fun, [:a, 1, 0]}} = Envelope.portable?(%{a: {0, {f}}})
      assert Envelope.portable?([1 | 2]) == :ok
      assert Envelope.portable?(%{{1, [2 | 3]} => %{x: <<1, 2>>}}) == :ok
    end

    test "plain data is portable" do
      assert Envelope.portable?(nil) == :ok
      assert Envelope.portable?(%{a: [1, {2, "x"}], b: %{c: self()}, d: make_ref()}) == :ok
    end

    test "structs are portable (and are searched for funs)" do
      # walk/2 enumerates maps with Enum.reduce_while/3, which goes through the Enumerable
      # protocol: a struct without it (Date, URI, Envelope, ...) raises
      # Protocol.UndefinedError, and a MapSet yields its elements, not {key, value} pairs
      # (FunctionClauseError). Agents whose state holds such a struct crash when they move.
      assert Envelope.portable?(%{d: ~D[2024-01-01]}) == :ok
      assert Envelope.portable?(MapSet.new([1, 2])) == :ok
      assert Envelope.portable?(%Envelope{id: "x", module: M}) == :ok

      assert Envelope.portable?(%Envelope{id: "x", module: M, state: fn -> 1 end}) ==
               {:error, {:not_portable, :fun, [:state]}}
    end

    test "funs are found with their path" do
      f = fn -> 1 end
      assert Envelope.portable?(f) == {:error, {:not_portable, :fun, []}}
      assert Envelope.portable?([1, 2, f]) == {:error, {:not_portable, :fun, [2]}}
      assert Envelope.portable?({:a, {:b, f}}) == {:error, {:not_portable, :fun, [1, 1]}}
      assert Envelope.portable?(%{a: %{b: [f]}}) == {:error, {:not_portable, :fun, [:a, :b, 0]}}
      assert Envelope.portable?(%{f => 1}) == {:error, {:not_portable, :fun, [{:key, f}]}}
      assert Envelope.portable?([1 | f]) == {:error, {:not_portable, :fun, [1]}}
      assert Envelope.portable?(&Enum.map/2) == {:error, {:not_portable, :fun, []}}
    end

    test "ports are found" do
      port = Port.open({:spawn, "cat"}, [])

      try do
        assert Envelope.portable?(%{p: port}) == {:error, {:not_portable, :port, [:p]}}
      after
        Port.close(port)
      end
    end
  end
end
