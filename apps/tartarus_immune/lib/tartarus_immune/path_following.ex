defmodule TartarusImmune.PathFollowing do
  @moduledoc """
  The path-following domain of thesis §6.5.11 for immune selection
  (`TartarusImmune.Domain`): which path-following algorithm (PFA) for which kind of
  sub-path, on the robot arena of `apps/tartarus_arena`.

  * An **instance** is one sub-path of one of the two closed paths
    (`TartarusArena.Paths`): set `:p1` (Path-1, 4 sub-paths) or `:p2` (Path-2, 5), index
    the sub-path's place on its path; the seed fixes the jitter of its features (and the
    world's noise when it is scored).
  * Its **features** are the sub-path's feature vector, Table 6.3's `[linearity,
    curvature, ninety, sharpness]` plus the instance's jitter.
  * The **solutions** are the eight PFA modules A1-A8 (`TartarusArena.PFAs`); each is
    self-contained, so an iPkt carries it as code.
  * The **score** really drives a robot over the sub-path with the PFA
    (`TartarusArena.Run.subpath/4`) and returns its cost (`time * (2 - on_line)`, or 3 x
    the time limit when the robot lost the line or timed out) divided by the sub-path's
    **nominal time** (its length at top speed, 0.25 m/s): `normalize/2`. So sub-paths of
    one type but different lengths score alike; 1.0 would be a run at top speed always on
    the line, and a failed run scores 12.0 (the time limit is 4 nominal times).

  In the selection experiment (`TartarusImmune.PathFollowing.Experiment`) the robots do
  not call `score/2`: a robot runs the chosen PFA in the shared arena and its measured
  cost, normalized the same way, is what feeds back. `score/2` is what trying a PFA on a
  sub-path alone costs (`TartarusImmune.Domain.class_best/4` over it is the exhaustive
  search the experiment is compared with).

      iex> alias TartarusImmune.PathFollowing
      iex> inst = PathFollowing.instance(:p1, 0, 1)
      iex> {inst.type, inst.features == PathFollowing.features(inst)}
      {:sp_c, true}
      iex> PathFollowing.sets()
      %{p1: 4, p2: 5}
  """
  @behaviour TartarusImmune.Domain

  alias TartarusArena.{PFAs, Paths, Run}

  @top_speed 0.25

  @typedoc "A sub-path instance."
  @type instance :: %{
          set: :p1 | :p2,
          index: non_neg_integer(),
          seed: integer(),
          type: Paths.type(),
          features: [float()],
          nominal: float()
        }

  @impl true
  @doc "The domain's name."
  def name, do: "path-following"

  @impl true
  @doc "Four features: linearity, curvature, ninety, sharpness."
  def feature_count, do: 4

  @impl true
  @doc "The sub-path instance's feature vector."
  def features(%{features: f}), do: f

  @impl true
  @doc "The eight PFAs, A1 to A8."
  def solutions, do: PFAs.all()

  @impl true
  @doc "A PFA's name, `\"A1\"` .. `\"A8\"`."
  def solution_name(pfa), do: PFAs.name(pfa)

  @impl true
  @doc "The normalized cost of driving `pfa` over the sub-path alone (see the moduledoc)."
  def score(pfa, %{set: set, index: i, seed: seed} = inst) do
    r = Run.subpath(pfa, path(set, seed), i, seed: seed)
    normalize(r.cost, inst)
  end

  @impl true
  @doc "`:p1` (Path-1's 4 sub-paths) and `:p2` (Path-2's 5)."
  def sets, do: %{p1: 4, p2: 5}

  @impl true
  @doc "Sub-path `index` of Path-1 (`:p1`) or Path-2 (`:p2`) under `seed`."
  def instance(set, index, seed) do
    sp = Enum.at(path(set, seed).subpaths, index) || raise ArgumentError, "no sub-path #{index}"

    %{
      set: set,
      index: index,
      seed: seed,
      type: sp.type,
      features: sp.features,
      nominal: (sp.to - sp.from) / @top_speed
    }
  end

  @doc """
  A cost of `TartarusArena.Run` (seconds) over the instance's nominal time, rounded to
  4 places.

      iex> inst = TartarusImmune.PathFollowing.instance(:p1, 0, 1)
      iex> TartarusImmune.PathFollowing.normalize(12.0, inst)
      2.0
  """
  @spec normalize(number(), instance()) :: float()
  def normalize(cost, %{nominal: nominal}), do: Float.round(cost / nominal, 4)

  @doc "The set of a path id: 1 -> `:p1`, 2 -> `:p2`."
  @spec set_of(1 | 2) :: :p1 | :p2
  def set_of(1), do: :p1
  def set_of(2), do: :p2

  @doc """
  Path-1 (`:p1` or 1) or Path-2 under `seed`, built once per BEAM node (kept in
  `:persistent_term`; a path is a few kB and a run uses a handful of seeds).
  """
  @spec path(:p1 | :p2 | 1 | 2, term()) :: Paths.t()
  def path(:p1, seed), do: path(1, seed)
  def path(:p2, seed), do: path(2, seed)

  def path(id, seed) do
    key = {__MODULE__, id, seed}

    case :persistent_term.get(key, nil) do
      nil ->
        p = Paths.path(id, seed)
        :persistent_term.put(key, p)
        p

      p ->
        p
    end
  end
end
