defmodule Tartarus.Strategy do
  @moduledoc """
  Migration strategies: how an agent picks where to go next.

  An agent's `{:move, dest, state}` action names either a host or a strategy:

    * `:random` - a neighbour chosen uniformly at random;
    * `:conscientious` - a neighbour the agent has never visited, else the one it visited
      least (thesis Appendix .1); ties are broken at random;
    * `{:gradient, signal}` - climbs the signal field `signal` (see `Tartarus.Signal`): the
      neighbour with the highest value of `signal` as this host knows it (each neighbour
      announces its value when it relays the signal here; a host-store entry
      `{:gradient, signal}` holding `%{neighbour => value}`, written by hand, overrides
      those values); ties are broken at random; falls back to conscientious when no
      neighbour carries the signal. It moves even from the top of the field (to the
      strongest neighbour): an agent that wants to stop at the source compares
      `Tartarus.Agent.signal/1` with `Tartarus.Agent.gradient/1` first;
    * `{:strategy, module, arg}` - a user strategy: `module` implements this behaviour.

  Random choices use the agent's own random state, which travels with it, so an agent's
  walk is reproducible for a given seed.

  This module is pure: it gets what the host knows and returns a choice.
  """

  @typedoc "What the strategy may look at."
  @type info :: %{
          here: Tartarus.host(),
          neighbours: [Tartarus.host()],
          visits: %{Tartarus.host() => non_neg_integer()},
          gradients: %{term() => %{Tartarus.host() => number()}}
        }

  @typedoc "A strategy as written in a move action."
  @type t :: :random | :conscientious | {:gradient, term()} | {:strategy, module(), term()}

  @doc "Chooses a destination. `rng` is a `:rand` state (not exported)."
  @callback choose(arg :: term(), info(), rng :: :rand.state()) ::
              {:ok, Tartarus.host(), :rand.state()} | {:error, term()}

  @doc """
  Chooses a destination among `info.neighbours`.

      iex> rng = :rand.seed_s(:exsss, {1, 2, 3})
      iex> info = %{here: {:a, :n}, neighbours: [{:b, :n}, {:c, :n}], visits: %{{:b, :n} => 2}, gradients: %{}}
      iex> {:ok, dest, _} = Tartarus.Strategy.choose(:conscientious, info, rng)
      iex> dest
      {:c, :n}
  """
  @spec choose(t(), info(), :rand.state()) ::
          {:ok, Tartarus.host(), :rand.state()} | {:error, term()}
  def choose(_strategy, %{neighbours: []}, _rng), do: {:error, :no_neighbours}

  def choose(:random, %{neighbours: ns}, rng) do
    {i, rng} = :rand.uniform_s(length(ns), rng)
    {:ok, Enum.at(ns, i - 1), rng}
  end

  def choose(:conscientious, %{neighbours: ns, visits: visits}, rng) do
    least = ns |> Enum.map(&Map.get(visits, &1, 0)) |> Enum.min()
    candidates = Enum.filter(ns, &(Map.get(visits, &1, 0) == least))
    choose(:random, %{neighbours: candidates}, rng)
  end

  def choose({:gradient, signal}, %{neighbours: ns} = info, rng) do
    strengths = info |> Map.get(:gradients, %{}) |> Map.get(signal, %{})

    case Enum.filter(ns, &Map.has_key?(strengths, &1)) do
      [] ->
        choose(:conscientious, info, rng)

      carrying ->
        best = carrying |> Enum.map(&strengths[&1]) |> Enum.max()

        case Enum.filter(carrying, &(strengths[&1] == best)) do
          [dest] -> {:ok, dest, rng}
          tied -> choose(:random, %{neighbours: tied}, rng)
        end
    end
  end

  def choose({:strategy, module, arg}, info, rng) when is_atom(module) do
    if Code.ensure_loaded?(module) and function_exported?(module, :choose, 3) do
      module.choose(arg, info, rng)
    else
      {:error, {:bad_strategy, {:strategy, module, arg}}}
    end
  end

  def choose(other, _info, _rng), do: {:error, {:bad_strategy, other}}

  @doc "True when `dest` names a strategy rather than a host."
  @spec strategy?(term()) :: boolean()
  def strategy?(:random), do: true
  def strategy?(:conscientious), do: true
  def strategy?({:gradient, _}), do: true
  def strategy?({:strategy, m, _}) when is_atom(m), do: true
  def strategy?(_), do: false
end
