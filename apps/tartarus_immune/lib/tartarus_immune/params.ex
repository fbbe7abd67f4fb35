defmodule TartarusImmune.Params do
  @moduledoc """
  The constants of thesis Table 6.1 (and the few choices the thesis leaves open), as one
  option schema with the thesis's defaults.

  | key | symbol | default | used in |
  |---|---|---|---|
  | `:mu` | μ | 0.5 | affinity threshold ψ_th = μ ψ_max (Eq. 6.7) |
  | `:sg_max` | Sg_max | 100 | danger strength at the distressed node (Eqs. 6.2-6.5) |
  | `:l_span` | l_span | 2 | danger signal span in hops (Eqs. 6.2-6.5) |
  | `:rho` | ρ | 2 | affinity-proportional mutation rate (Eq. 6.14) |
  | `:alpha` | α | 0.4 | stimulation scale (Eq. 6.8) |
  | `:delta` | δ | 0.2 | suppression scale (Eq. 6.9) |
  | `:gamma` | γ (Table 6.1's σ) | 1 | discounted penalty factor (Eq. 6.9) |
  | `:nu` | ν | 0.6 | variance of the Gaussian of hypermutation (Eq. 6.15) |
  | `:gamma_max` | Γ_max | 1000 | hops an iPkt may take (Eq. 6.16) |
  | `:tau_min` | τ_min | 5 | activation a clone costs; below it an iPkt dies (Eqs. 6.13, 6.17) |
  | `:tau_max` | τ_max | 20 | the largest activation (Eq. 6.11; activations are capped there) |
  | `:q_max` | Q_max (Table 6.1's v) | 5 | the interaction queue's size (Eq. 6.12) |
  | `:tau_init` | - | 10 | activation of an iPkt created at the start or added on the fly |
  | `:clone_tau` | - | `:tau_min` | activation a clone starts with (`:tau_min`: the τ_min its parent paid for it, Eq. 6.13; or a number) |
  | `:nc_round` | - | `:floor` | how Eq. 6.11's NC becomes a count: `:floor`, `:round` or `:ceil` |
  | `:nc_cap` | - | `:survive` | `:survive`: a parent makes no more clones than leave it at τ_min or above; `:none`: Eq. 6.13 as printed |
  | `:lin` | - | `:types` | who interacts in a LIN round: each pair of solutions once (`Maths.interact_types/2`) or each pair of iPkts (`Maths.interact/2`) |
  | `:score_window` | - | 50 | problems in the running mean of an iPkt's performance score ζ |
  | `:score_ref` | - | `:instance` | what a cost is divided by in ζ (`:interact` only): `:instance`, the domain's scale of the instance (`TartarusImmune.Domain.score_scale/2`); `:best_candidate`, the cheapest candidate on the same instance |
  | `:signal_life` | T_life (Eq. 6.5) | `:period` | how long iPkts follow a danger signal: `:period`, its whole barrage period at every hop; `:eq6_5`, a fraction T_life(H)/Sg_max = Sg(H)/Sg_max of it (ΔT_life = ΔSg, Eqs. 6.2-6.3: the whole period at the source, half of it one hop away), Sg_max standing for the period; `:distressed`, re-diffused every round (lives one round) while the host has a pending problem; `:unserved`, the same but not while the host's interaction queue is full (Q_current ≥ Q_max): `TartarusImmune.Node.danger_call/3` |
  | `:clamp_fv` | - | true | mutated feature values are clamped to [0, 1] (features are normalized) |

  Table 6.1 lists `σ = 1` and `v = 5`, symbols that appear in no equation; Eq. 6.9 has a γ
  and Eqs. 6.11-6.12 a Q_max that Table 6.1 does not list. We read σ as γ and v as Q_max.

  `:score_ref`: a cost divided by the cheapest candidate present (`:best_candidate`, the
  first choice) measures a solution against whoever happened to be on the host: a
  solution alone on a host is "the best" of itself and scores 1.0 on every problem, so a
  solution that first wins a few hosts by luck carries a perfect score to the next host and
  suppresses a better rival there (on the sorting set P1 this gave the near-tie IS/SelS to
  SelS in 5 of 10 seeds). `:instance` divides by a scale of the instance alone, so a score
  is the solution's own.
  """

  @schema [
    mu: [type: {:range, 0, 1}, default: 0.5, doc: "μ: affinity threshold factor (Eq. 6.7)"],
    sg_max: [
      type: {:range, 1.0e-3, 1.0e6},
      default: 100,
      doc: "Sg_max: danger strength at the source"
    ],
    l_span: [type: :pos_integer, default: 2, doc: "l_span: danger signal span in hops"],
    rho: [type: {:range, 0, 100}, default: 2, doc: "ρ: mutation decay with affinity (Eq. 6.14)"],
    alpha: [type: {:range, 0, 100}, default: 0.4, doc: "α: stimulation scale (Eq. 6.8)"],
    delta: [type: {:range, 0, 100}, default: 0.2, doc: "δ: suppression scale (Eq. 6.9)"],
    gamma: [
      type: {:range, 0, 100},
      default: 1,
      doc: "γ (Table 6.1's σ): penalty factor (Eq. 6.9)"
    ],
    nu: [
      type: {:range, 0, 100},
      default: 0.6,
      doc: "ν: variance of the mutation Gaussian (Eq. 6.15)"
    ],
    gamma_max: [type: :pos_integer, default: 1000, doc: "Γ_max: hops to apoptosis (Eq. 6.16)"],
    tau_min: [
      type: {:range, 1.0e-3, 1.0e6},
      default: 5,
      doc: "τ_min: cost of a clone, death below (6.13, 6.17)"
    ],
    tau_max: [
      type: {:range, 1.0e-3, 1.0e6},
      default: 20,
      doc: "τ_max: largest activation (Eq. 6.11)"
    ],
    q_max: [type: :non_neg_integer, default: 5, doc: "Q_max (Table 6.1's v): queue size"],
    tau_init: [
      type: {:range, 0, 1.0e6},
      default: 10,
      doc: "activation of a new (not cloned) iPkt"
    ],
    clone_tau: [
      type: {:or, [{:in, [:tau_min]}, :number]},
      default: :tau_min,
      doc: "activation of a clone"
    ],
    nc_round: [type: {:in, [:floor, :round, :ceil]}, default: :floor, doc: "NC to a count"],
    nc_cap: [
      type: {:in, [:survive, :none]},
      default: :survive,
      doc: "cap NC so the parent keeps τ >= τ_min"
    ],
    score_window: [
      type: :pos_integer,
      default: 50,
      doc: "problems in the running mean of the performance score ζ"
    ],
    score_ref: [
      type: {:in, [:instance, :best_candidate]},
      default: :instance,
      doc: "ζ's reference: the instance's own scale, or the cheapest candidate present"
    ],
    signal_life: [
      type: {:in, [:period, :eq6_5, :distressed, :unserved, :unmet]},
      default: :period,
      doc:
        "a danger signal lives its barrage period at every hop, (Eq. 6.5) a fraction Sg(H)/Sg_max of it, or one round, re-diffused while the host has a pending problem (:distressed) and room in its queue (:unserved)"
    ],
    lin: [
      type: {:in, [:types, :ipkts]},
      default: :types,
      doc: "who interacts: solutions (once per pair) or every pair of iPkts"
    ],
    clamp_fv: [type: :boolean, default: true, doc: "clamp mutated features to [0, 1]"]
  ]

  @typedoc "Validated parameters (a map with every key of the schema)."
  @type t :: %{atom() => term()}

  @doc false
  def schema, do: @schema

  @doc """
  Validates `opts` against the schema (see the moduledoc) and returns a map with every key.

      iex> {:ok, p} = TartarusImmune.Params.new(mu: 0.6)
      iex> {p.mu, p.alpha, p.q_max}
      {0.6, 0.4, 5}
      iex> TartarusImmune.Params.new(nc_round: :up)
      {:error, "invalid options given to TartarusImmune.Params.new/1 for key :nc_round: expected one of [:floor, :round, :ceil], got: :up"}
  """
  @spec new(keyword() | map()) :: {:ok, t()} | {:error, String.t()}
  def new(opts \\ []) do
    opts = if is_map(opts), do: Map.to_list(opts), else: opts

    with {:ok, kw} <- Tartarus.Options.validate(opts, @schema, "TartarusImmune.Params.new/1") do
      {:ok, Map.new(kw)}
    end
  end

  @doc "Like `new/1`, raising `ArgumentError` on invalid options."
  @spec new!(keyword() | map()) :: t()
  def new!(opts \\ []) do
    case new(opts) do
      {:ok, p} -> p
      {:error, msg} -> raise ArgumentError, msg
    end
  end

  @doc "The keys of the schema."
  @spec keys() :: [atom()]
  def keys, do: Keyword.keys(@schema)
end
