defmodule TartarusEmu.DynamicsTest do
  use ExUnit.Case, async: true

  alias TartarusEmu.Dynamics

  doctest Dynamics

  # Runs `ticks` steps over `n` nodes; returns the fraction of node-ticks spent down.
  defp down_fraction(p, n, ticks, seed) do
    start = {0, Dynamics.new(Enum.to_list(1..n)), Dynamics.rng(seed)}

    {down_ticks, _, _} =
      Enum.reduce(1..ticks, start, fn _, {down_ticks, state, rng} ->
        {_events, state, rng} = Dynamics.step(state, p, rng)
        {down_ticks + length(Dynamics.down(state)), state, rng}
      end)

    down_ticks / (n * ticks)
  end

  test "with one p a node is down half the time, whatever p" do
    for p <- [0.05, 0.2, 0.5] do
      fraction = down_fraction(p, 20, 2_000, 7)
      assert_in_delta fraction, 0.5, 0.03, "p = #{p}: down fraction #{fraction}"
    end
  end

  test "with {p_break, p_heal} the down fraction is p_break / (p_break + p_heal)" do
    fraction = down_fraction({0.1, 0.3}, 20, 3_000, 11)
    assert_in_delta fraction, 0.25, 0.02
  end

  test "down spells last 1 / p_heal ticks on average" do
    # Count down ticks and completed spells: mean spell length ~ 1 / p_heal = 5.
    nodes = for i <- 1..20, do: i

    {down_ticks, recoveries, _, _} =
      Enum.reduce(1..5_000, {0, 0, Dynamics.new(nodes), Dynamics.rng(3)}, fn _,
                                                                             {d, r, state, rng} ->
        {events, state, rng} = Dynamics.step(state, {0.1, 0.2}, rng)

        {d + length(Dynamics.down(state)), r + Enum.count(events, &match?({:up, _}, &1)), state,
         rng}
      end)

    assert_in_delta down_ticks / recoveries, 5.0, 0.4
  end

  test "deterministic by seed, independent of the global random state" do
    state = Dynamics.new([:a, :b, :c])
    :rand.seed(:exsss, 99)
    a = Dynamics.run(state, 0.3, 50, Dynamics.rng(5))
    :rand.seed(:exsss, 100)
    assert Dynamics.run(state, 0.3, 50, Dynamics.rng(5)) == a
    refute Dynamics.run(state, 0.3, 50, Dynamics.rng(6)) == a
  end

  test "events alternate per node and match the state" do
    {events, state, _} = Dynamics.run(Dynamics.new([:a, :b]), 0.4, 200, Dynamics.rng(1))

    for node <- [:a, :b] do
      kinds = for {_tick, {kind, ^node}} <- events, do: kind
      assert kinds |> Enum.chunk_every(2, 2, :discard) |> Enum.all?(&(&1 == [:down, :up]))
      assert Dynamics.up?(state, node) == (kinds == [] or List.last(kinds) == :up)
    end

    assert state.tick == 200
  end

  test "link flapping over edges and live_edges/3" do
    edges = MapSet.new([{:a, :b}, {:b, :c}])
    nodes = Dynamics.new([:a, :b, :c])
    {_, links, _} = Dynamics.step(Dynamics.new(MapSet.to_list(edges)), 1.0, Dynamics.rng(1))
    assert Dynamics.live_edges(edges, nodes) == edges
    assert Dynamics.live_edges(edges, nodes, links) == MapSet.new()
  end

  test "bad probabilities are refused clearly" do
    assert_raise ArgumentError,
                 "Dynamics.step/3: expected p to be a number between 0 and 1, got: 1.5",
                 fn -> Dynamics.step(Dynamics.new([:a]), 1.5, Dynamics.rng(1)) end

    assert_raise ArgumentError, ~r/expected p_heal to be a number between 0 and 1, got: :x/, fn ->
      Dynamics.step(Dynamics.new([:a]), {0.1, :x}, Dynamics.rng(1))
    end
  end
end
