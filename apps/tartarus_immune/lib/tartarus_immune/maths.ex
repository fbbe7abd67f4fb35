defmodule TartarusImmune.Maths do
  @moduledoc """
  The equations of thesis chapter 6 (Eqs. 6.2-6.17) as pure functions, with batch forms.
  Every function takes the parameters `p` of `TartarusImmune.Params` (a map; Table 6.1's
  defaults).

  | Eq. | function |
  |---|---|
  | 6.2, 6.3 | `delta_sg/1`, `delta_life/1` |
  | 6.4, 6.5 | `strength/2`, `lifetime/2` |
  | 6.6 | `affinity/2`, `affinities/2` (batch), `psi_max/1` |
  | 6.7 | `threshold/2`, `candidates/3` (batch) |
  | 6.8 | `stimulation/3` |
  | 6.9 | `suppression/3` |
  | 6.10 | `activation/3`, `interact/2` and `interact_types/2` (the whole localized idiotypic network at once) |
  | 6.11, 6.12 | `cloning_space/2`, `clones/3` |
  | 6.13 | `after_cloning/3` |
  | 6.14 | `mutation_rate/2` |
  | 6.15 | `hypermutate/4` |
  | 6.16 | `life/2` |
  | 6.17 | `apoptosis?/3`, `survivors/2` (batch) |

  ## Choices where the thesis is ambiguous

    * **Who interacts** (Eqs. 6.8-6.9): the candidates for one problem instance (affinity
      ≥ ψ_th); for every pair `i`, `j` of different solutions where `i` has the strictly
      better performance score ζ, `i` receives `Sti_i^j` and `j` receives `Sup_j^i`.
      Equal scores, and two iPkts of one solution, neither stimulate nor suppress. All
      updates of one round use the activations from before the round (a synchronous Farmer
      step).
    * **Pressure per solution** (`p.lin`, default `:types`): a solution interacts with each
      other solution once per problem (`interact_types/2`, over the means of its iPkts), so
      ten iPkts of a winner do not suppress a loser ten times; `:ipkts` makes every pair of
      iPkts interact (`interact/2`), which turns an early lead into a monopoly within a few
      steps.
    * **The performance score ζ** an iPkt carries (§6.4.1: "an ID, activation value and a
      performance score") is `running_score/4`: the running mean of its solution's
      normalized cost over the last `score_window` problems it took part in; every distinct
      candidate solution runs on the instance. The cost is divided by a reference chosen by
      `p.score_ref` (see `TartarusImmune.Params`): by default the instance's own scale
      (`TartarusImmune.Domain.score_scale/2`), which no other solution changes. A clone
      inherits its parent's ζ.
    * **Caps**: an activation is capped at τ_max after Eq. 6.10 (τ_max is "the maximum value
      of activation an iPkt can have").
    * **NC** (Eq. 6.11) becomes a count by `p.nc_round` (`:floor` by default), never below 0;
      with `p.nc_cap == :survive` (the default) a parent makes at most as many clones as
      leave it at τ_min or above (`:none`: Eq. 6.13 as written, a parent may pay itself to
      death).
    * **Hypermutation** (Eq. 6.15): ν is the variance, so each feature moves by
      `λ * sqrt(ν) * z` with `z` standard normal; with `p.clamp_fv` the result is clamped to
      [0, 1] (features are normalized).
  """

  @type fv :: [number()]
  @type p :: map()

  # -- danger signals (6.2-6.5) -------------------------------------------------------

  @doc """
  Eq. 6.2: the strength lost per hop, `ΔSg = Sg_max / l_span`.

      iex> TartarusImmune.Maths.delta_sg(%{sg_max: 100, l_span: 2})
      50.0
  """
  @spec delta_sg(p()) :: float()
  def delta_sg(p), do: p.sg_max / p.l_span

  @doc """
  Eq. 6.3: the lifetime lost per hop, `ΔT_life = Sg_max / l_span` (as printed).

      iex> TartarusImmune.Maths.delta_life(%{sg_max: 90, l_span: 3})
      30.0
  """
  @spec delta_life(p()) :: float()
  def delta_life(p), do: p.sg_max / p.l_span

  @doc """
  Eq. 6.4: the danger strength at `h` hops from the distressed node; 0 beyond l_span.

      iex> p = %{sg_max: 100, l_span: 2}
      iex> for h <- 0..3, do: TartarusImmune.Maths.strength(h, p)
      [100.0, 50.0, 0.0, 0.0]
  """
  @spec strength(non_neg_integer(), p()) :: float()
  def strength(0, p), do: p.sg_max * 1.0
  def strength(h, p) when h <= p.l_span, do: max(strength(h - 1, p) - delta_sg(p), 0.0)
  def strength(_h, _p), do: 0.0

  @doc """
  Eq. 6.5: the danger lifetime at `h` hops (in the unit of Sg_max); 0 beyond l_span.

      iex> for h <- 0..2, do: TartarusImmune.Maths.lifetime(h, %{sg_max: 100, l_span: 4})
      [100.0, 75.0, 50.0]
  """
  @spec lifetime(non_neg_integer(), p()) :: float()
  def lifetime(0, p), do: p.sg_max * 1.0
  def lifetime(h, p) when h <= p.l_span, do: max(lifetime(h - 1, p) - delta_life(p), 0.0)
  def lifetime(_h, _p), do: 0.0

  # -- affinity (6.6, 6.7) ------------------------------------------------------------

  @doc """
  ψ_max = sqrt(n) for feature vectors of length `n`.

      iex> TartarusImmune.Maths.psi_max(4)
      2.0
  """
  @spec psi_max(non_neg_integer()) :: float()
  def psi_max(n), do: :math.sqrt(n)

  @doc """
  Eq. 6.6: affinity `ψ = ψ_max - ||fx - fy||` of two feature vectors of equal length.

      iex> TartarusImmune.Maths.affinity([0, 0, 0, 0], [0, 0, 0, 0])
      2.0
      iex> TartarusImmune.Maths.affinity([0.0, 0.3, 0, 0], [0.0, 0.0, 0.4, 0])
      1.5
  """
  @spec affinity(fv(), fv()) :: float()
  def affinity(fx, fy) when length(fx) == length(fy) do
    psi_max(length(fx)) - distance(fx, fy)
  end

  @doc "Euclidean distance between two feature vectors."
  @spec distance(fv(), fv()) :: float()
  def distance(a, b) do
    a
    |> Enum.zip(b)
    |> Enum.reduce(0.0, fn {x, y}, acc -> acc + (x - y) * (x - y) end)
    |> :math.sqrt()
  end

  @doc """
  Batch Eq. 6.6: the affinities of `fx` to each vector of `fys`.

      iex> TartarusImmune.Maths.affinities([0, 0], [[0, 0], [1, 1], [0.6, 0.8]])
      [1.4142135623730951, 0.0, 0.41421356237309515]
  """
  @spec affinities(fv(), [fv()]) :: [float()]
  def affinities(fx, fys), do: Enum.map(fys, &affinity(fx, &1))

  @doc """
  Eq. 6.7: the threshold `ψ_th = μ ψ_max` for vectors of length `n`.

      iex> TartarusImmune.Maths.threshold(4, %{mu: 0.5})
      1.0
  """
  @spec threshold(non_neg_integer(), p()) :: float()
  def threshold(n, p), do: p.mu * psi_max(n)

  @doc """
  True when `fy` recognizes `fx`: `ψ(fx, fy) >= ψ_th`.

      iex> TartarusImmune.Maths.recognizes?([0, 0, 0, 0], [1, 0, 0, 0], %{mu: 0.5})
      true
      iex> TartarusImmune.Maths.recognizes?([0, 0, 0, 0], [1, 0.1, 0, 0], %{mu: 0.5})
      false
  """
  @spec recognizes?(fv(), fv(), p()) :: boolean()
  def recognizes?(fx, fy, p), do: affinity(fx, fy) >= threshold(length(fx), p) - 1.0e-12

  @doc """
  Batch Eq. 6.7: the indices (0-based) of the vectors of `fys` that recognize `fx`.

      iex> TartarusImmune.Maths.candidates([0, 0, 0, 0], [[1, 1, 1, 1], [0.5, 0, 0, 0], [0, 0, 0, 1]], %{mu: 0.5})
      [1, 2]
  """
  @spec candidates(fv(), [fv()], p()) :: [non_neg_integer()]
  def candidates(fx, fys, p) do
    fys
    |> Enum.with_index()
    |> Enum.filter(fn {fy, _} -> recognizes?(fx, fy, p) end)
    |> Enum.map(&elem(&1, 1))
  end

  # -- the localized idiotypic network (6.8-6.10) -------------------------------------

  @doc """
  Eq. 6.8: the stimulation `Sti_i^j = ψ(F_yi, F_yj) + α τ_j` that a better solution `i`
  receives from `j`, given their affinity `psi_ij` and `j`'s activation.

      iex> TartarusImmune.Maths.stimulation(1.5, 10, %{alpha: 0.4})
      5.5
  """
  @spec stimulation(number(), number(), p()) :: float()
  def stimulation(psi_ij, tau_j, p), do: psi_ij + p.alpha * tau_j * 1.0

  @doc """
  Eq. 6.9: the suppression `Sup_j^i = γ ψ(F_yi, F_yj) + δ τ_i` that a worse solution `j`
  receives from `i`, given their affinity and `i`'s activation.

      iex> TartarusImmune.Maths.suppression(1.5, 10, %{gamma: 1, delta: 0.2})
      3.5
  """
  @spec suppression(number(), number(), p()) :: float()
  def suppression(psi_ij, tau_i, p), do: p.gamma * psi_ij + p.delta * tau_i * 1.0

  @doc """
  Eq. 6.10 (Farmer's discrete update): `τ = τ_prev + Sti - Sup`.

      iex> TartarusImmune.Maths.activation(10, 5.5, 3.5)
      12.0
  """
  @spec activation(number(), number(), number()) :: float()
  def activation(tau_prev, sti, sup), do: tau_prev + sti - sup * 1.0

  @doc """
  One round of the localized idiotypic network (Eqs. 6.8-6.10) over `members`, maps with
  `:fv`, `:tau` and `:cost` (the performance score ζ, lower is better) and optionally
  `:kind` (the solution): returns, in order, maps with the new `:tau` (capped at τ_max),
  and the round's `:sti` and `:sup` totals. Pairs of equal cost, and pairs of the same
  `:kind`, do not interact; all updates use the activations from before the round.

      iex> p = %{alpha: 0.4, delta: 0.2, gamma: 1, tau_max: 20}
      iex> ms = [%{fv: [0, 0, 0, 0], tau: 10, cost: 3}, %{fv: [0.3, 0, 0.4, 0], tau: 10, cost: 7}]
      iex> TartarusImmune.Maths.interact(ms, p)
      [%{tau: 15.5, sti: 5.5, sup: 0.0}, %{tau: 6.5, sti: 0.0, sup: 3.5}]
  """
  @spec interact([map()], p()) :: [%{tau: float(), sti: float(), sup: float()}]
  def interact(members, p) do
    indexed = Enum.with_index(members)

    for {m, i} <- indexed do
      {sti, sup} =
        Enum.reduce(indexed, {0.0, 0.0}, fn
          {_, ^i}, acc ->
            acc

          {o, _}, {sti, sup} ->
            cond do
              kin?(m, o) -> {sti, sup}
              m.cost < o.cost -> {sti + stimulation(affinity(m.fv, o.fv), o.tau, p), sup}
              m.cost > o.cost -> {sti, sup + suppression(affinity(o.fv, m.fv), o.tau, p)}
              true -> {sti, sup}
            end
        end)

      %{tau: min(activation(m.tau, sti, sup), p.tau_max * 1.0), sti: sti, sup: sup}
    end
  end

  @doc """
  One round of the localized idiotypic network between **solutions** rather than iPkts
  (`p.lin == :types`, the default): the members (with `:kind`) are grouped by kind; each
  group is represented by its mean feature vector, mean activation and mean score; for
  every pair of kinds the better one's members each receive `Sti` (Eq. 6.8, computed from
  the representatives) and the worse one's members each receive `Sup` (Eq. 6.9), once per
  pair of kinds however many iPkts each has. So a solution's population does not multiply
  the pressure it puts on the others (which `interact/2` does). Same output as
  `interact/2`.

      iex> p = %{alpha: 0.4, delta: 0.2, gamma: 1, tau_max: 20}
      iex> ms = [%{fv: [0.0], tau: 10, cost: 1.0, kind: :a}, %{fv: [0.0], tau: 10, cost: 1.0, kind: :a}, %{fv: [0.0], tau: 10, cost: 2.0, kind: :b}]
      iex> TartarusImmune.Maths.interact_types(ms, p) |> Enum.map(& &1.tau)
      [15.0, 15.0, 7.0]
  """
  @spec interact_types([map()], p()) :: [%{tau: float(), sti: float(), sup: float()}]
  def interact_types(members, p) do
    reps =
      members
      |> Enum.group_by(& &1.kind)
      |> Map.new(fn {k, ms} ->
        n = length(ms)
        fv = ms |> Enum.map(& &1.fv) |> Enum.zip_with(&(Enum.sum(&1) / n))

        {k,
         %{
           fv: fv,
           tau: Enum.sum(Enum.map(ms, & &1.tau)) / n,
           cost: Enum.sum(Enum.map(ms, & &1.cost)) / n
         }}
      end)

    deltas =
      Map.new(reps, fn {k, r} ->
        Enum.reduce(reps, {k, {0.0, 0.0}}, fn
          {^k, _}, acc ->
            acc

          {_, o}, {k, {sti, sup}} ->
            cond do
              r.cost < o.cost -> {k, {sti + stimulation(affinity(r.fv, o.fv), o.tau, p), sup}}
              r.cost > o.cost -> {k, {sti, sup + suppression(affinity(o.fv, r.fv), o.tau, p)}}
              true -> {k, {sti, sup}}
            end
        end)
      end)

    for m <- members do
      {sti, sup} = deltas[m.kind]
      %{tau: min(activation(m.tau, sti, sup), p.tau_max * 1.0), sti: sti, sup: sup}
    end
  end

  defp kin?(%{kind: k}, %{kind: k}), do: true
  defp kin?(_, _), do: false

  @doc """
  The performance score ζ an iPkt carries after taking part in one more problem: the
  running mean of its normalized costs `r` (its solution's cost divided by the reference
  of `p.score_ref`, lower is better) over its last `window` problems (`zeta` nil: none
  yet). Returns `{zeta, n}`.

      iex> TartarusImmune.Maths.running_score(nil, 0, 1.5, 20)
      {1.5, 1}
      iex> TartarusImmune.Maths.running_score(1.5, 1, 1.0, 20)
      {1.25, 2}
      iex> TartarusImmune.Maths.running_score(2.0, 20, 1.0, 20)
      {1.95, 20}
  """
  @spec running_score(number() | nil, non_neg_integer(), number(), pos_integer()) ::
          {float(), non_neg_integer()}
  def running_score(nil, _n, r, _window), do: {r * 1.0, 1}

  def running_score(zeta, n, r, window) do
    k = min(n + 1, window)
    {zeta + (r - zeta) / k, k}
  end

  @doc """
  The index of the member with the largest activation (Algorithm 4, line 19); ties go to
  the lower cost, then to the earlier member. `nil` for no members.

      iex> TartarusImmune.Maths.select([%{tau: 3, cost: 1}, %{tau: 9, cost: 5}, %{tau: 9, cost: 2}])
      2
  """
  @spec select([map()]) :: non_neg_integer() | nil
  def select([]), do: nil

  def select(members) do
    members
    |> Enum.with_index()
    |> Enum.min_by(fn {m, i} -> {-m.tau, m.cost, i} end)
    |> elem(1)
  end

  # -- cloning and population control (6.11-6.13) ------------------------------------

  @doc """
  Eq. 6.12: `CloningSpace = Q_max - Q_current`, never below 0 (a full or overfull queue
  leaves no space).

      iex> TartarusImmune.Maths.cloning_space(5, 3)
      2
      iex> TartarusImmune.Maths.cloning_space(5, 7)
      0
  """
  @spec cloning_space(non_neg_integer(), non_neg_integer()) :: non_neg_integer()
  def cloning_space(q_max, q_current), do: max(q_max - q_current, 0)

  @doc """
  Eq. 6.11: the number of clones `NC = CloningSpace * τ / τ_max` of an iPkt of activation
  `tau` at a node whose queue holds `q_current` iPkts, as a count (`p.nc_round`, at least
  0; with `p.nc_cap == :survive`, also at most `floor((τ - τ_min) / τ_min)`).

      iex> p = %{q_max: 5, tau_max: 20, tau_min: 5, nc_round: :floor, nc_cap: :none}
      iex> TartarusImmune.Maths.clones(20, 2, p)
      3
      iex> TartarusImmune.Maths.clones(15, 2, p)
      2
      iex> TartarusImmune.Maths.clones(20, 5, p)
      0
      iex> TartarusImmune.Maths.clones(20, 0, %{p | nc_cap: :survive})
      3
  """
  @spec clones(number(), non_neg_integer(), p()) :: non_neg_integer()
  def clones(tau, q_current, p) do
    raw = cloning_space(p.q_max, q_current) * tau / p.tau_max

    nc =
      case Map.get(p, :nc_round, :floor) do
        :floor -> floor(raw)
        :round -> round(raw)
        :ceil -> ceil(raw)
      end
      |> max(0)

    case Map.get(p, :nc_cap, :survive) do
      :survive -> min(nc, max(floor((tau - p.tau_min) / p.tau_min), 0))
      :none -> nc
    end
  end

  @doc """
  Eq. 6.13: the activation left after making `nc` clones, `τ = τ_prev - NC τ_min`.

      iex> TartarusImmune.Maths.after_cloning(20, 3, %{tau_min: 5})
      5.0
  """
  @spec after_cloning(number(), non_neg_integer(), p()) :: float()
  def after_cloning(tau, nc, p), do: tau - nc * p.tau_min * 1.0

  # -- hypermutation (6.14, 6.15) -----------------------------------------------------

  @doc """
  Eq. 6.14: `λ = exp(-ρ ψ_norm)` with `ψ_norm = ψ / ψ_max`.

      iex> TartarusImmune.Maths.mutation_rate(0.0, %{rho: 2})
      1.0
      iex> Float.round(TartarusImmune.Maths.mutation_rate(0.5, %{rho: 2}), 6)
      0.367879
  """
  @spec mutation_rate(number(), p()) :: float()
  def mutation_rate(psi_norm, p), do: :math.exp(-p.rho * psi_norm)

  @doc """
  Eq. 6.15: each feature `F_yi + λ(ψ_norm) G(0, ν)`, given standard normal draws `zs`
  (one per feature; the caller draws them from the agent's travelling stream). ν is a
  variance: the Gaussian's standard deviation is `sqrt(ν)`. Clamped to [0, 1] with
  `p.clamp_fv`.

      iex> p = %{rho: 2, nu: 0.25, clamp_fv: true}
      iex> TartarusImmune.Maths.hypermutate([0.5, 0.5, 0.9], 0.0, [1.0, -2.0, 1.0], p)
      [1.0, 0.0, 1.0]
      iex> TartarusImmune.Maths.hypermutate([0.5], 0.0, [0.2], p)
      [0.6]
  """
  @spec hypermutate(fv(), number(), [float()], p()) :: fv()
  def hypermutate(fv, psi_norm, zs, p) when length(fv) == length(zs) do
    scale = mutation_rate(psi_norm, p) * :math.sqrt(p.nu)

    fv
    |> Enum.zip(zs)
    |> Enum.map(fn {f, z} ->
      v = f + scale * z
      if Map.get(p, :clamp_fv, true), do: v |> max(0.0) |> min(1.0), else: v
    end)
  end

  # -- apoptosis (6.16, 6.17) ----------------------------------------------------------

  @doc """
  Eq. 6.16: hops left before apoptosis after `h` hops, `Γ(H) = Γ_max - H` (not below 0).

      iex> TartarusImmune.Maths.life(0, %{gamma_max: 1000})
      1000
      iex> TartarusImmune.Maths.life(1000, %{gamma_max: 1000})
      0
  """
  @spec life(non_neg_integer(), p()) :: non_neg_integer()
  def life(h, p), do: max(p.gamma_max - h, 0)

  @doc """
  Eq. 6.17: an iPkt with `gamma` hops left and activation `tau` dies when
  `Γ = 0 or τ < τ_min`.

      iex> TartarusImmune.Maths.apoptosis?(0, 20, %{tau_min: 5})
      true
      iex> TartarusImmune.Maths.apoptosis?(3, 4.9, %{tau_min: 5})
      true
      iex> TartarusImmune.Maths.apoptosis?(3, 5, %{tau_min: 5})
      false
  """
  @spec apoptosis?(non_neg_integer(), number(), p()) :: boolean()
  def apoptosis?(gamma, tau, p), do: gamma <= 0 or tau < p.tau_min

  @doc """
  Batch Eq. 6.17: the indices of the members (maps with `:gamma` and `:tau`) that live.

      iex> TartarusImmune.Maths.survivors([%{gamma: 1, tau: 6}, %{gamma: 0, tau: 9}, %{gamma: 5, tau: 2}], %{tau_min: 5})
      [0]
  """
  @spec survivors([map()], p()) :: [non_neg_integer()]
  def survivors(members, p) do
    members
    |> Enum.with_index()
    |> Enum.reject(fn {m, _} -> apoptosis?(m.gamma, m.tau, p) end)
    |> Enum.map(&elem(&1, 1))
  end
end
