defmodule TartarusWarehouse.Roam do
  @moduledoc """
  How task agents move (a `Tartarus.Strategy`): conscientiously (the least visited
  neighbour, thesis Appendix .1), among the neighbours that are robots when there are any,
  else among all (secondary nodes only relay agents). Use it as
  `{:strategy, TartarusWarehouse.Roam, robots}` with `robots` the set of robot hosts,
  `{:prefix, p}` (robots are the hosts whose name starts with `p`: cheap to carry however
  many robots there are), or `nil` to treat every neighbour alike.

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
    case Enum.filter(info.neighbours, &robot?(robots, &1)) do
      [] -> Tartarus.Strategy.choose(:conscientious, info, rng)
      ns -> Tartarus.Strategy.choose(:conscientious, %{info | neighbours: ns}, rng)
    end
  end

  @doc """
  True if `host` is a robot by `robots` (a set of hosts, or `{:prefix, p}`).

      iex> TartarusWarehouse.Roam.robot?({:prefix, "emu1-r"}, {"emu1-r7", :n})
      true
      iex> TartarusWarehouse.Roam.robot?({:prefix, "emu1-r"}, {"emu1-s7", :n})
      false
  """
  @spec robot?(MapSet.t() | {:prefix, String.t()}, Tartarus.host()) :: boolean()
  def robot?({:prefix, p}, {name, _node}) when is_binary(name), do: String.starts_with?(name, p)
  def robot?({:prefix, _p}, _host), do: false
  def robot?(%MapSet{} = robots, host), do: MapSet.member?(robots, host)
end
