defmodule TartarusImmune.Evolution.Repertoire do
  @moduledoc """
  A robot's antibody repertoire and the operations of thesis Algorithm 5, as pure functions.

  An **antibody** (`t:antibody/0`) has a paratope (a normalized sensor vector: the centre of
  its active region), a controller evolved by the (1+1)-online strategy
  (`TartarusImmune.Evolution.ES`, whose champion is the controller's weight vector), a
  concentration and an id. The **epitope** of the current antigen is the normalized sensor
  vector the robot reads now.

  One round of Algorithm 5 is `recognize/3` (lines 5-16) then `select/4` (lines 17-21):

    * affinity `psi` is the Euclidean distance between epitope and paratope (lower is
      closer); antibodies with `psi <= epsilon` (the cross-reactivity threshold) are the
      **candidates**;
    * each candidate is stimulated: its concentration grows by
      `stimulation * (1 - psi / epsilon)`. The thesis says "by an amount proportional to
      their respective psi values"; we read it as proportional to the affinity (closer
      antibodies gain more), since psi is a distance here;
    * if there is no candidate, a new antibody is created with the epitope as paratope,
      random weights and the minimal concentration `c_min`, ids counting from 1;
    * the best antibody (highest concentration) is chosen among the candidates, or, with
      probability `p_sharing` and when the external repertoire (antibodies shared by peers)
      has one whose paratope matches the epitope, among those. Algorithm 5's listing
      tests `random() < P_sharing` for the *internal* choice; we give `p_sharing` the
      meaning its name has (the probability of taking a shared antibody), which is the
      same rule with `1 - p`. A shared antibody that is chosen is copied into the internal
      repertoire (same id and origin, so a robot never holds two copies of one);
    * after an evaluation period the controller's fitness feeds back with `report/3`: the
      concentration becomes the mean of the old concentration and the fitness (better
      controllers, higher concentration, as the thesis asks), and antibodies whose
      concentration fell to zero or below are purged (`purge/1`).

  Options of `new/1`: `epsilon` (required), `shape` (default `[4, 5, 2]`), `c_min` (0.1),
  `stimulation` (0.1), `p_sharing` (0.1), `es` (options for each antibody's strategy).

  Antibodies are keyed `{origin, id}`:

      iex> alias TartarusImmune.Evolution.Repertoire
      iex> rep = Repertoire.new(epsilon: 0.3, shape: [2, 1], origin: :r1)
      iex> {rep, [{:r1, 1}], rng} = Repertoire.recognize(rep, [0.0, 0.0], :rand.seed_s(:exsss, 1))
      iex> {rep, [{:r1, 1}], rng} = Repertoire.recognize(rep, [0.1, 0.0], rng)
      iex> {rep, [{:r1, 2}], _} = Repertoire.recognize(rep, [0.9, 0.9], rng)
      iex> map_size(rep.antibodies)
      2
  """

  alias TartarusImmune.Evolution.{ES, NeuralNet}

  defstruct antibodies: %{},
            next_id: 1,
            epsilon: nil,
            shape: [4, 5, 2],
            c_min: 0.1,
            stimulation: 0.1,
            p_sharing: 0.1,
            es: [],
            origin: nil

  @typedoc "An antibody: `origin` is the robot that created it (nil: this one)."
  @type antibody :: %{
          id: pos_integer(),
          origin: term(),
          paratope: [float()],
          es: ES.t(),
          concentration: float()
        }

  @type t :: %__MODULE__{
          antibodies: %{term() => antibody()},
          next_id: pos_integer(),
          epsilon: float(),
          shape: NeuralNet.shape(),
          c_min: float(),
          stimulation: float(),
          p_sharing: float(),
          es: keyword(),
          origin: term()
        }

  @doc "An empty repertoire (a tabula rasa). See the module doc for the options."
  @spec new(keyword()) :: t()
  def new(opts) do
    epsilon = Keyword.fetch!(opts, :epsilon)

    unless is_number(epsilon) and epsilon > 0,
      do:
        raise(
          ArgumentError,
          "expected :epsilon to be a positive number, got: #{inspect(epsilon)}"
        )

    struct!(__MODULE__, Keyword.put(opts, :epsilon, epsilon * 1.0))
  end

  @doc """
  Affinity: the Euclidean distance between two vectors (lower is closer).

      iex> TartarusImmune.Evolution.Repertoire.affinity([0.0, 0.0], [0.3, 0.4])
      0.5
  """
  @spec affinity([number()], [number()]) :: float()
  def affinity(a, b) do
    a
    |> Enum.zip(b)
    |> Enum.reduce(0.0, fn {x, y}, s -> s + (x - y) * (x - y) end)
    |> :math.sqrt()
  end

  @doc """
  The candidates for an epitope among `antibodies` (a map or list): `[{key, psi}]` with
  `psi <= epsilon`, closest first.
  """
  @spec candidates(t(), [number()], map() | list()) :: [{term(), float()}]
  def candidates(%__MODULE__{} = rep, ep, antibodies \\ nil) do
    (antibodies || rep.antibodies)
    |> Enum.flat_map(fn {key, ab} ->
      psi = affinity(ep, ab.paratope)
      if psi <= rep.epsilon, do: [{key, psi}], else: []
    end)
    |> Enum.sort_by(fn {key, psi} -> {psi, key} end)
  end

  @doc """
  Lines 5-16 of Algorithm 5: stimulates the candidates for `ep`, or creates a new antibody
  when there is none. Returns `{repertoire, candidate_keys, rng}`.
  """
  @spec recognize(t(), [number()], :rand.state()) :: {t(), [term()], :rand.state()}
  def recognize(%__MODULE__{} = rep, ep, rng) do
    case candidates(rep, ep) do
      [] ->
        {weights, rng} = NeuralNet.random(rep.shape, rng)
        key = {rep.origin, rep.next_id}

        ab = %{
          id: rep.next_id,
          origin: rep.origin,
          paratope: Enum.map(ep, &(&1 * 1.0)),
          es: ES.new(weights, rep.es),
          concentration: rep.c_min
        }

        {%{rep | antibodies: Map.put(rep.antibodies, key, ab), next_id: rep.next_id + 1}, [key],
         rng}

      cands ->
        abs =
          Enum.reduce(cands, rep.antibodies, fn {key, psi}, abs ->
            Map.update!(abs, key, fn ab ->
              %{ab | concentration: ab.concentration + rep.stimulation * (1 - psi / rep.epsilon)}
            end)
          end)

        {%{rep | antibodies: abs}, Enum.map(cands, &elem(&1, 0)), rng}
    end
  end

  @doc """
  Lines 17-21 of Algorithm 5: the key of the antibody to run for `ep`, chosen among the
  candidate keys or (with probability `p_sharing`) among the matching antibodies of the
  external repertoire `xrep` (a map key => antibody, as shared by peers); a shared one is
  copied into the repertoire. Returns `{repertoire, key, :internal | :external, rng}`.
  """
  @spec select(t(), [term()], [number()], map(), :rand.state()) ::
          {t(), term(), :internal | :external, :rand.state()}
  def select(%__MODULE__{} = rep, cand_keys, ep, xrep, rng) do
    {u, rng} = :rand.uniform_s(rng)

    external =
      if map_size(xrep) > 0 and u < rep.p_sharing, do: candidates(rep, ep, xrep), else: []

    case external do
      [] ->
        {rep, best(cand_keys, rep.antibodies), :internal, rng}

      ext ->
        key = best(Enum.map(ext, &elem(&1, 0)), xrep)

        {%{rep | antibodies: Map.put(rep.antibodies, key, Map.fetch!(xrep, key))}, key, :external,
         rng}
    end
  end

  defp best(keys, abs) do
    Enum.max_by(keys, fn key -> {abs[key].concentration, neg(key)} end)
  end

  # Ties go to the older antibody (lower id).
  defp neg({_origin, id}), do: -id
  defp neg(_), do: 0

  @doc """
  Feeds an evaluation back: the antibody's concentration becomes the mean of its old
  concentration and `fitness`. Then purges antibodies at zero concentration or below.
  """
  @spec report(t(), term(), number()) :: t()
  def report(%__MODULE__{} = rep, key, fitness) do
    abs =
      Map.update!(rep.antibodies, key, &%{&1 | concentration: (&1.concentration + fitness) / 2})

    purge(%{rep | antibodies: abs})
  end

  @doc "Removes antibodies whose concentration is zero or below."
  @spec purge(t()) :: t()
  def purge(%__MODULE__{} = rep) do
    %{rep | antibodies: Map.reject(rep.antibodies, fn {_k, ab} -> ab.concentration <= 0 end)}
  end

  @doc "Replaces an antibody's strategy (after an evaluation of its controller)."
  @spec put_es(t(), term(), ES.t()) :: t()
  def put_es(%__MODULE__{} = rep, key, es),
    do: %{rep | antibodies: Map.update!(rep.antibodies, key, &%{&1 | es: es})}
end
