defmodule TartarusLats.Test.Appendix do
  @moduledoc false
  # The thesis's Appendix .2: ten nodes a..j, the door at d only; X walks
  # d -> e -> f -> i -> h and stays at h. Shared by the query tests.
  #
  #   b
  #   a   c
  #   d - e - f - g
  #       h - i - j

  alias TartarusLats.{Building, World}

  @doc false
  def world do
    positions = %{
      b: {0, 18, 0},
      a: {0, 9, 0},
      c: {9, 9, 0},
      d: {0, 0, 0},
      e: {9, 0, 0},
      f: {18, 0, 0},
      g: {27, 0, 0},
      h: {9, -9, 0},
      i: {18, -9, 0},
      j: {27, -9, 0}
    }

    adjacency = %{a: [:b, :c, :d], d: [:e], e: [:f], f: [:g, :i], i: [:h, :j]}
    building = Building.custom(positions: positions, adjacency: adjacency, entrances: [:d])

    script = %{
      name: :x,
      enter_at: 0,
      entrance: :d,
      route: [{:d, 20}, {:e, 20}, {:f, 20}, {:i, 20}, {:h, 10_000}],
      exit: :h
    }

    World.new(building: building, walkers: 0, scripts: [script])
  end
end
