defmodule TartarusWarehouse.Roam do
  @moduledoc """
  How task agents move (a `Tartarus.Strategy`): conscientiously (the least visited
  neighbour, thesis Appendix .1), among the neighbours that are robots when there are any,
  else among all (secondary nodes only relay agents). Use it as
  `{:strategy, TartarusWarehouse.Roam, robots}` with `robots` the set of robot hosts, or
  `nil` to treat every neighbour alike.

      iex> rng = :rand.seed_s(:exsss, {1, 2, 3})
      iex> info = %{here: :x, neighbours: [:s1, :r1, :r2], visits: %{r1: 3}, gradients: %{}}
      iex> {:ok, dest, _} = TartarusWarehouse.Roam.choose(MapSet.new([:r1, :r2]), info, rng)
      iex> dest
      :r2
  """
  @behaviour Tartarus.Strategy

  @impl true
  def choose(nil, info, rng), do: Tartarus.Strategy.choose(:conscientious, info, rng)

  def choose(robots, info, rng) do
    case Enum.filter(info.neighbours, &MapSet.member?(robots, &1)) do
      [] -> Tartarus.Strategy.choose(:conscientious, info, rng)
      ns -> Tartarus.Strategy.choose(:conscientious, %{info | neighbours: ns}, rng)
    end
  end
end
