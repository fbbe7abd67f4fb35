defmodule TartarusImmune.IPkt do
  @moduledoc """
  An intelligent packet (iPkt, thesis §6.4.1): an ordinary mobile agent that carries one
  solution module (shipped with it as code, `Tartarus.Agent.add_module/1`), the feature
  vector it maps that solution to (F_y), its activation τ and its hop count (Eq. 6.16).

  On every host it enters the host's interaction queue (it posts `{:enter, id, info}` to
  the host's `TartarusImmune.Node` agent, named `"immune"`) and leaves it before it moves.

  On `{:go, epoch}` (the step's move phase) it:

    1. dies when its hops are used up (Eq. 6.17, Γ = 0);
    2. stays when the host has a pending problem it recognizes (ψ ≥ ψ_th), or when sharing
       is off (`sharing: false`), or, with `sharing: :clones`, unless it is a clone that has
       not moved yet (then only fresh clones travel, each once, and an iPkt otherwise stays
       in the repertoire of the host where it was made or arrived: thesis §6.5.11's robots
       keep their mappings and share clones);
    3. else climbs the danger field `{:danger, tag}` (`{:gradient, ...}` strategy) when a
       danger signal at this host carries a feature vector it recognizes (and danger
       signals are on); `{:go, tag, age}` names the field (the barrage's epoch, or
       `{epoch, step}` for a signal diffused per round, see `TartarusImmune.Node.danger_call/3`);
    4. else moves conscientiously.

  The node tells it its new activation and performance score (`{:update, tau, {zeta,
  n}}`), to clone (`{:clone, n, psi_norm, tau_after, {zeta, n}, clone_tau}`: it makes `n` clones here, one per `:clone_next` it sends itself) and to die
  (`:die`). A clone (`ctx.clone_of` set) starts with the clone activation, no hops, a new
  tag, and its F_y hypermutated (Eq. 6.15) with normal draws from its own travelling random
  stream (`Tartarus.Agent.normal/0`), so the same seed gives the same mutations.

  Every arrival, stay, birth and death is reported to the driver (the experiment process)
  as `{:immune, run, event, tag, solution}` (deaths ordered by a node are reported by the
  node), so a step can wait for exactly what it set in motion.
  """
  use Tartarus.Agent

  alias Tartarus.Clock
  alias TartarusImmune.Maths

  require Tartarus.Clock

  @doc """
  Creates a fresh iPkt of solution `sol` mapped to feature vector `fv` on `host`, for an
  experiment's driver (the calling process): activation `tau_init`, no score yet, `serial`
  as its tag and, with the run's seed, its random stream. `st` holds the run's `p`
  (parameters), `run`, `seed` and options `o` (`sharing`, `danger`).
  """
  @spec create(Tartarus.host_ref(), module(), [float()], pos_integer(), map()) ::
          {:ok, String.t()} | {:error, term()}
  def create(host, sol, fv, serial, st) do
    s = %{
      sol: sol,
      fv: fv,
      tau: st.p.tau_init * 1.0,
      zeta: nil,
      n: 0,
      hops: 0,
      tag: serial,
      clones: 0,
      plan: nil,
      p: st.p,
      driver: self(),
      run: st.run,
      sharing: st.o.sharing,
      danger: st.o.danger
    }

    Tartarus.create_mobile_agent(host, __MODULE__, s, seed: {st.seed, serial})
  end

  @doc false
  def init(s) do
    :ok = Tartarus.Agent.add_module(s.sol)
    enter(s)
    {:stay, s}
  end

  @doc false
  def handle_arrival(%{clone_of: parent}, s) when parent != nil and s.plan != nil do
    zs = for _ <- s.fv, do: Tartarus.Agent.normal()

    s = %{
      s
      | fv: Maths.hypermutate(s.fv, s.plan.psi_norm, zs, s.p),
        tau: s.plan.clone_tau,
        hops: 0,
        tag: {s.tag, s.clones},
        clones: 0,
        plan: nil
    }

    enter(s)
    notify(s, :born)
    {:stay, s}
  end

  def handle_arrival(_ctx, s) do
    s = %{s | hops: s.hops + 1}
    enter(s)
    notify(s, :arrived)
    {:stay, s}
  end

  @doc false
  def handle_message({:update, tau, {zeta, n}}, _from, s),
    do: {:stay, %{s | tau: tau, zeta: zeta, n: n}}

  def handle_message({:clone, k, psi_norm, tau_after, {zeta, n}, clone_tau}, _from, s) do
    for _ <- 1..k//1, do: send(self(), :clone_next)

    {:stay,
     %{
       s
       | tau: tau_after,
         zeta: zeta,
         n: n,
         plan: %{psi_norm: psi_norm, clone_tau: clone_tau}
     }}
  end

  def handle_message(:die, _from, s), do: {:stop, :normal, s}

  def handle_message(_other, _from, s), do: {:stay, s}

  @doc false
  def handle_info(:clone_next, s) do
    s = %{s | clones: s.clones + 1}
    {:clone, :here, s}
  end

  def handle_info({:go, epoch}, s), do: handle_info({:go, epoch, 0.0}, s)

  # `age`: the fraction of the barrage period gone by (for `signal_life: :eq6_5`)
  def handle_info({:go, epoch, age}, s) do
    s = %{s | plan: nil}

    cond do
      Maths.life(s.hops, s.p) == 0 ->
        leave()
        notify(s, :expired)
        {:stop, :normal, s}

      s.sharing == false or pending_match?(s) or (s.sharing == :clones and not fresh_clone?(s)) ->
        notify(s, :stayed)
        {:stay, s}

      s.danger and danger_match?(s, epoch, age) ->
        leave()
        {:move, {:gradient, {:danger, epoch}}, s}

      true ->
        leave()
        {:move, :conscientious, s}
    end
  end

  def handle_info(_other, s), do: {:stay, s}

  @doc false
  def handle_move_failed(_dest, _reason, _ctx, s) do
    enter(s)
    notify(s, :move_failed)
    {:stay, s}
  end

  # a clone that has not moved yet (sharing :clones: the only iPkts that travel)
  defp fresh_clone?(s), do: is_tuple(s.tag) and s.hops == 0

  defp notify(s, event), do: send(s.driver, {:immune, s.run, event, s.tag, s.sol})

  @doc """
  The driver's side of the reports above: the next report of an iPkt of run `run` as
  `{event, solution}`, waiting at most `timeout` ms; if none comes, raises `message`
  (an iPkt that never answers is a bug of the experiment, not something to wait out).

      iex> run = make_ref()
      iex> send(self(), {:immune, run, :arrived, 7, :a1})
      iex> TartarusImmune.IPkt.next_event(run, 100, "no report")
      {:arrived, :a1}
      iex> TartarusImmune.IPkt.next_event(run, 0, "no report")
      ** (RuntimeError) no report
  """
  @spec next_event(reference(), timeout(), String.t()) :: {atom(), term()}
  def next_event(run, timeout, message) do
    Clock.receive do
      {:immune, ^run, ev, _tag, sol} -> {ev, sol}
    after
      timeout -> raise message
    end
  end

  defp enter(s) do
    info = %{sol: s.sol, fv: s.fv, tau: s.tau, hops: s.hops, tag: s.tag, zeta: s.zeta, n: s.n}
    :ok = Tartarus.post({"immune", Tartarus.Agent.host()}, {:enter, Tartarus.Agent.id(), info})
  end

  defp leave do
    :ok = Tartarus.post({"immune", Tartarus.Agent.host()}, {:leave, Tartarus.Agent.id()})
  end

  defp pending_match?(s) do
    Tartarus.Agent.store_get(:immune_pending, [])
    |> Enum.any?(&Maths.recognizes?(&1, s.fv, s.p))
  end

  # Eq. 6.5 (`signal_life: :eq6_5`): a contribution lives T_life(H) = its strength Sg(H)
  # (ΔT_life = ΔSg, Eqs. 6.2-6.3), Sg_max standing for the barrage period
  defp danger_match?(s, epoch, age) do
    {:danger, epoch}
    |> Tartarus.Agent.signals()
    |> Enum.any?(fn %{data: fvs, value: v} ->
      alive?(s.p, v, age) and Enum.any?(fvs, &Maths.recognizes?(&1, s.fv, s.p))
    end)
  end

  defp alive?(%{signal_life: :eq6_5, sg_max: max}, v, age), do: age < v / max
  defp alive?(_p, _v, _age), do: true
end
