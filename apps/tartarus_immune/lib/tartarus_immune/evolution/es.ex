defmodule TartarusImmune.Evolution.ES do
  @moduledoc """
  The (1+1)-online evolutionary strategy (Bredeche, Haasdijk and Eiben 2009) that evolves a
  selected antibody's controller on board (thesis §7.2.2), as pure functions.

  One **champion** (weights and its fitness) and one step size `sigma`. Each evaluation
  period:

    1. `propose/2` makes an offspring: every weight plus `N(0, sigma)` (clamped to
       `[-w_max, w_max]`); with probability `p_reeval` it proposes the champion itself
       instead, to be evaluated again (on a robot a lucky evaluation should not stay
       champion for ever; the new value replaces the old one, `reevaluate: true`);
    2. the robot runs what was proposed and measures its fitness (higher is better);
    3. `tell/3` with that fitness: an offspring that does **better** than the champion
       replaces it and `sigma` goes back to `sigma_min`; one that does not is dropped and
       `sigma` **doubles**, up to `sigma_max` (the thesis: "the value of sigma doubles if
       the offspring performs lower than the parent").

  Constants (options of `new/2`) and their defaults: `sigma_min` 0.1 (also the initial
  sigma), `sigma_max` 4.0, `w_max` 4.0, `p_reeval` 0.0 (evaluations here are noise free
  unless a scenario says otherwise). Bredeche et al. use sigma in [0.01, 4] on weights in
  [-4, 4]; 0.1 as the floor makes an offspring differ visibly from its parent within a
  200-iteration run.

      iex> alias TartarusImmune.Evolution.ES
      iex> es = ES.new([0.0, 0.0], fitness: 0.5)
      iex> {:offspring, w, rng} = ES.propose(es, :rand.seed_s(:exsss, 1))
      iex> length(w) == 2 and is_tuple(rng)
      true
      iex> ES.tell(es, {:offspring, w}, 0.9).champion == w
      true
      iex> ES.tell(es, {:offspring, w}, 0.1).sigma
      0.2
  """

  defstruct champion: [],
            fitness: nil,
            sigma: 0.1,
            sigma_min: 0.1,
            sigma_max: 4.0,
            w_max: 4.0,
            p_reeval: 0.0,
            evaluations: 0,
            improvements: 0

  @type t :: %__MODULE__{
          champion: [float()],
          fitness: number() | nil,
          sigma: float(),
          sigma_min: float(),
          sigma_max: float(),
          w_max: float(),
          p_reeval: float(),
          evaluations: non_neg_integer(),
          improvements: non_neg_integer()
        }

  @typedoc "What `propose/2` asks the robot to evaluate."
  @type proposal :: {:offspring, [float()]} | {:champion, [float()]}

  @doc """
  A strategy whose champion is `weights`. Options: `:fitness` (the champion's, if known;
  default nil: the first offspring always wins), `:sigma_min`, `:sigma_max`, `:w_max`,
  `:p_reeval`.
  """
  @spec new([float()], keyword()) :: t()
  def new(weights, opts \\ []) do
    min = Keyword.get(opts, :sigma_min, 0.1)

    %__MODULE__{
      champion: weights,
      fitness: Keyword.get(opts, :fitness),
      sigma: min,
      sigma_min: min,
      sigma_max: Keyword.get(opts, :sigma_max, 4.0),
      w_max: Keyword.get(opts, :w_max, 4.0),
      p_reeval: Keyword.get(opts, :p_reeval, 0.0)
    }
  end

  @doc """
  What to evaluate next: `{:offspring, weights, rng}` or, with probability `p_reeval` (and
  only once the champion has a fitness), `{:champion, weights, rng}`.
  """
  @spec propose(t(), :rand.state()) :: {:offspring | :champion, [float()], :rand.state()}
  def propose(%__MODULE__{} = es, rng) do
    {u, rng} = if es.p_reeval > 0, do: :rand.uniform_s(rng), else: {1.0, rng}

    if u < es.p_reeval and es.fitness != nil do
      {:champion, es.champion, rng}
    else
      {w, rng} = mutate(es.champion, es.sigma, es.w_max, rng)
      {:offspring, w, rng}
    end
  end

  @doc """
  Gaussian mutation: each weight plus `N(0, sigma)`, clamped to `[-w_max, w_max]`.
  Returns `{weights, rng}`.
  """
  @spec mutate([float()], float(), float(), :rand.state()) :: {[float()], :rand.state()}
  def mutate(weights, sigma, w_max, rng) do
    Enum.map_reduce(weights, rng, fn w, rng ->
      {z, rng} = :rand.normal_s(rng)
      {w |> Kernel.+(sigma * z) |> max(-w_max) |> min(w_max), rng}
    end)
  end

  @doc """
  The measured fitness of what `propose/2` gave (pass the proposal as `{kind, weights}`).
  Returns the new strategy.
  """
  @spec tell(t(), proposal(), number()) :: t()
  def tell(%__MODULE__{} = es, {:champion, _w}, fitness),
    do: %{es | fitness: fitness, evaluations: es.evaluations + 1}

  def tell(%__MODULE__{} = es, {:offspring, w}, fitness) do
    es = %{es | evaluations: es.evaluations + 1}

    if es.fitness == nil or fitness > es.fitness do
      %{
        es
        | champion: w,
          fitness: fitness,
          sigma: es.sigma_min,
          improvements: es.improvements + 1
      }
    else
      %{es | sigma: min(es.sigma * 2, es.sigma_max)}
    end
  end

  @doc """
  Adopts a foreign controller (shared by a peer) as champion if it is better than the own:
  `fitness` is the foreign one's as measured here. Returns `{:adopted | :kept, es}`.
  """
  @spec adopt(t(), [float()], number()) :: {:adopted | :kept, t()}
  def adopt(%__MODULE__{} = es, weights, fitness) do
    if es.fitness == nil or fitness > es.fitness,
      do: {:adopted, %{es | champion: weights, fitness: fitness, sigma: es.sigma_min}},
      else: {:kept, es}
  end
end
