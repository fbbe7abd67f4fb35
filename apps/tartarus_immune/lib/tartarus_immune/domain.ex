defmodule TartarusImmune.Domain do
  @moduledoc """
  A problem domain for immune selection: how an instance looks as a feature vector, which
  solutions exist, what a solution costs on an instance, and the data sets.

  The mechanism (`TartarusImmune.Maths`, the agents, the experiment) knows a domain only
  through this behaviour, so the same mechanism can select sorting algorithms
  (`TartarusImmune.Sorting`), path-following algorithms for robots (thesis §6.5.11) or
  anything else with a cost.

  * An **instance** is identified by `{set, index}` and materialized by `c:instance/3`
    (generators are seeded: the same seed gives the same instance on any node).
  * A **solution** is a module (it travels as code with the iPkts that carry it) with a
    short name (`c:solution_name/1`, e.g. `"QS"`).
  * `c:features/1` maps an instance to a normalized feature vector (each value in 0..1, of
    length `c:feature_count/0`).
  * `c:score/2` really runs a solution on an instance and returns its cost (lower is
    better), deterministic unless the domain says otherwise.
  """

  @typedoc "A data set's name."
  @type set :: atom()
  @typedoc "An instance's identity."
  @type ref :: {set(), non_neg_integer()}

  @doc "The domain's name."
  @callback name() :: String.t()
  @doc "The length of a feature vector."
  @callback feature_count() :: pos_integer()
  @doc "The normalized feature vector (values in 0..1) of an instance."
  @callback features(instance :: term()) :: [float()]
  @doc "Every solution module the domain knows, in a fixed order."
  @callback solutions() :: [module()]
  @doc "A solution's short name."
  @callback solution_name(module()) :: String.t()
  @doc "The cost of running `solution` on `instance` (lower is better)."
  @callback score(solution :: module(), instance :: term()) :: number()
  @doc "The data sets and their sizes."
  @callback sets() :: %{set() => pos_integer()}
  @doc "Instance `index` of `set` under `seed`."
  @callback instance(set(), index :: non_neg_integer(), seed :: integer()) :: term()

  @doc """
  Optional: a positive scale of `instance` that depends on the instance alone (its size),
  by which a solution's cost is divided to make its performance score, so that costs on
  instances of different sizes can be averaged and a score does not depend on which other
  solutions happened to run beside it (see `TartarusImmune.Params`, `:score_ref`).
  Without it the scale is 1.
  """
  @callback score_scale(instance :: term()) :: number()

  @optional_callbacks score_scale: 1

  @doc """
  `domain.score_scale(instance)` if the domain defines it, else 1.

      iex> TartarusImmune.Domain.score_scale(TartarusImmune.Sorting, [1, 2])
      1.0
      iex> TartarusImmune.Domain.score_scale(Enum, [1, 2])
      1
  """
  @spec score_scale(module(), term()) :: number()
  def score_scale(domain, instance) do
    Code.ensure_loaded(domain)

    if function_exported?(domain, :score_scale, 1),
      do: domain.score_scale(instance),
      else: 1
  end

  @doc """
  The oracle: the solution of `solutions` with the lowest cost on `instance` (ties: the
  earlier in `solutions`), and every solution's cost.
  """
  @spec oracle(module(), [module()], term()) :: {module(), %{module() => number()}}
  def oracle(domain, solutions, instance) do
    costs = Map.new(solutions, &{&1, domain.score(&1, instance)})
    best = Enum.min_by(solutions, &costs[&1])
    {best, costs}
  end

  @doc """
  The best solution of a whole set by mean cost over `refs` (ties: the earlier), and the
  mean cost of each: what "the known best" of a class means here.
  """
  @spec class_best(module(), [module()], [ref()], integer()) ::
          {module(), %{module() => float()}}
  def class_best(domain, solutions, refs, seed) do
    totals =
      Enum.reduce(refs, Map.new(solutions, &{&1, 0}), fn {set, i}, acc ->
        inst = domain.instance(set, i, seed)
        Map.new(acc, fn {s, t} -> {s, t + domain.score(s, inst)} end)
      end)

    means = Map.new(totals, fn {s, t} -> {s, t / max(length(refs), 1)} end)
    {Enum.min_by(solutions, &means[&1]), means}
  end
end
