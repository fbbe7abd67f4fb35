defmodule TartarusImmune.Node do
  @moduledoc """
  A node's side of Algorithm 4: a static agent named `"immune"` on every host (created by
  the network's setup hook), holding the host's **interaction queue** (the iPkts resident
  here, as they announced themselves) and its **pending problems**.

  Messages:

    * `{:enter, id, info}`, `{:leave, id}` - from iPkts arriving and leaving;
    * `{:problems, refs, epoch}` (a request, answered `:ok` once done) - a barrage: the instances are materialized
      (`domain.instance/3`), their feature vectors are published in the host store
      (`:immune_pending`, read by the iPkts) and, when danger signals are on, the node
      emits the danger signal `{:danger, epoch}` of strength Sg_max and span l_span (the
      platform's linear law is Eq. 6.4), carrying the feature vectors;
    * `:interact` (a request) - solves the oldest pending problem: the resident iPkts that
      recognize it are the candidates (Eq. 6.7), each distinct candidate solution runs on the
      instance (its score), one LIN round updates their activations (Eqs. 6.8-6.10), the
      one of largest activation is selected and allowed `NC` clones (Eqs. 6.11-6.13, the
      queue's length being Q_current), and candidates whose activation fell below τ_min die
      (Eq. 6.17). A problem no resident iPkt recognizes stays pending. Answers a report
      map;
    * `:queue` (a request) - the queue's entries.

  The decisions are the pure function `interact/4`; this module only carries them out.
  """
  use Tartarus.Agent

  alias TartarusImmune.{Cache, Maths}

  @doc false
  def init(s), do: {:stay, Map.merge(%{queue: %{}, problems: []}, s)}

  @doc false
  def handle_message({:enter, id, info}, _from, s), do: {:stay, put_in(s.queue[id], info)}
  def handle_message({:leave, id}, _from, s), do: {:stay, %{s | queue: Map.delete(s.queue, id)}}

  def handle_message({:problems, refs, epoch}, from, s) do
    new =
      for {set, i} = ref <- refs do
        inst = s.domain.instance(set, i, s.seed)
        %{ref: ref, inst: inst, fv: s.domain.features(inst)}
      end

    problems = s.problems ++ new
    publish(problems)

    if s.danger and new != [] do
      :ok =
        Tartarus.Agent.emit_signal({:danger, epoch}, s.p.sg_max,
          span: s.p.l_span,
          data: Enum.map(new, & &1.fv)
        )
    end

    # answered once the signal is emitted, so the driver's settle waits for its field
    Tartarus.Agent.reply(from, :ok)
    {:stay, %{s | problems: problems}}
  end

  def handle_message(:interact, from, %{problems: []} = s) do
    Tartarus.Agent.reply(from, %{executed: nil, born: 0, died: []})
    {:stay, s}
  end

  def handle_message(:interact, from, %{problems: [pb | rest]} = s) do
    members = s.queue |> Enum.sort_by(fn {_id, m} -> m.tag end)

    score = fn sol -> Cache.score(s.domain, sol, pb.ref, s.seed, pb.inst) end

    case interact(members, pb.fv, score, Map.put(s.p, :q_current, map_size(s.queue))) do
      :no_candidates ->
        Tartarus.Agent.reply(from, %{executed: nil, waiting: pb.ref, born: 0, died: []})
        {:stay, s}

      d ->
        host = Tartarus.Agent.host()

        for {id, tau} <- d.taus,
            id != d.selected,
            do: :ok = Tartarus.post({id, host}, {:tau, tau})

        for id <- d.dead, do: :ok = Tartarus.post({id, host}, :die)

        if d.selected not in d.dead do
          msg =
            if d.nc > 0,
              do: {:clone, d.nc, d.psi_norm, d.tau_after, d.scores[d.selected], clone_tau(s.p)},
              else: {:update, d.tau_after, d.scores[d.selected]}

          :ok = Tartarus.post({d.selected, host}, msg)
        end

        queue =
          Enum.reduce(d.taus, s.queue, fn {id, t}, q ->
            {z, n} = d.scores[id]
            update_in(q[id], &%{&1 | tau: t, zeta: z, n: n})
          end)
          |> then(&put_in(&1[d.selected].tau, d.tau_after))
          |> Map.drop(d.dead)

        publish(rest)

        Tartarus.Agent.reply(from, %{
          executed: s.queue[d.selected].sol,
          ref: pb.ref,
          cost: d.costs[s.queue[d.selected].sol],
          costs: d.costs,
          born: d.nc,
          died: Enum.map(d.dead, &s.queue[&1].sol)
        })

        {:stay, %{s | queue: queue, problems: rest}}
    end
  end

  def handle_message(:queue, from, s) do
    Tartarus.Agent.reply(from, Map.values(s.queue))
    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  @doc false
  def handle_info(_msg, s), do: {:stay, s}

  @doc """
  The decisions of one interaction (Algorithm 4, lines 9-21) for a problem of feature
  vector `fx`, pure. `members` are `{id, %{sol:, fv:, tau:}}` in queue order; `score`
  gives a solution's cost on the instance; `p` holds the parameters and `:q_current`.
  Returns `:no_candidates`, or a map with the candidates' new activations `:taus`
  (`[{id, tau}]`) and performance scores `:scores` (`%{id => {zeta, n}}`), the `:selected` id, its clone count `:nc`, its activation after
  cloning `:tau_after`, the normalized affinity `:psi_norm` of its F_y to `fx` (for
  hypermutation), the ids that die (`:dead`) and the `:costs` per solution.
  """
  @spec interact([{term(), map()}], [float()], (module() -> number()), map()) ::
          :no_candidates | map()
  def interact(members, fx, score, p) do
    cands = Enum.filter(members, fn {_id, m} -> Maths.recognizes?(fx, m.fv, p) end)

    if cands == [] do
      :no_candidates
    else
      costs =
        cands |> Enum.map(fn {_, m} -> m.sol end) |> Enum.uniq() |> Map.new(&{&1, score.(&1)})

      best = costs |> Map.values() |> Enum.min() |> max(1)

      zetas =
        Enum.map(cands, fn {_, m} ->
          Maths.running_score(m.zeta, m.n, costs[m.sol] / best, p.score_window)
        end)

      ms =
        Enum.zip_with(cands, zetas, fn {_, m}, {z, _} ->
          %{fv: m.fv, tau: m.tau, cost: z, kind: m.sol}
        end)

      new =
        if Map.get(p, :lin, :types) == :types,
          do: Maths.interact_types(ms, p),
          else: Maths.interact(ms, p)

      after_round = Enum.zip_with(ms, new, fn m, n -> %{m | tau: n.tau} end)
      sel_i = Maths.select(after_round)
      {sel_id, sel} = Enum.at(cands, sel_i)
      sel_tau = Enum.at(after_round, sel_i).tau
      nc = if sel_tau < p.tau_min, do: 0, else: Maths.clones(sel_tau, p.q_current, p)
      taus = Enum.zip_with(cands, new, fn {id, _}, n -> {id, n.tau} end)
      scores = Enum.zip_with(cands, zetas, fn {id, _}, z -> {id, z} end) |> Map.new()
      tau_after = Maths.after_cloning(sel_tau, nc, p)

      dead =
        for {id, t} <- taus, t2 = if(id == sel_id, do: tau_after, else: t), t2 < p.tau_min, do: id

      %{
        taus: taus,
        selected: sel_id,
        nc: nc,
        tau_after: tau_after,
        psi_norm: Maths.affinity(fx, sel.fv) / Maths.psi_max(length(fx)),
        dead: dead,
        costs: costs,
        scores: scores
      }
    end
  end

  defp clone_tau(%{clone_tau: :tau_min, tau_min: t}), do: t * 1.0
  defp clone_tau(%{clone_tau: t}), do: t * 1.0

  defp publish(problems),
    do: :ok = Tartarus.Agent.store_put(:immune_pending, Enum.map(problems, & &1.fv))
end
