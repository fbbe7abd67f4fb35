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
    * `{:diffuse, tag}` (a request, answered `true` if a signal went out) - with a
      per-round danger signal (`signal_life: :distressed | :unserved`; then `{:problems,
      ...}` emits none), the host decides whether it calls for help this round
      (`danger_call/3`) and if so emits `{:danger, tag}` carrying the feature vectors of its
      pending problems;
    * `:queue` (a request) - the queue's entries;
    * `:pending` (a request) - how many problems are pending;
    * `:served` (a request) - whether a resident iPkt recognizes one of the pending
      problems (`served?/3`).

  ## Deferred measurement (a robot)

  Where a solution's cost is known only after it has run, and only one can run (a robot
  crossing a sub-path with one path-following algorithm, `TartarusImmune.PathFollowing`),
  an interaction is cut in two; the pending problem is registered and signalled with
  `{:problems, refs, epoch}` as above:

    * `:choose` (a request) - the resident iPkts that recognize the oldest pending problem
      are the candidates; one LIN round (Eqs. 6.8-6.10) over the performance scores ζ the
      candidates **carry** (no solution is run), the candidate of largest activation is
      selected and the losers below τ_min die (Eq. 6.17). A candidate never measured
      (ζ nil: a solution just injected) has nothing to compare and takes no part in the
      round; by default it is selected first, so each new solution is tried once
      (`choose/3`; `p.explore` and `p.n_min` set other exploration policies).
      `{:choose, overrides}` is the same with `overrides` (a map or keyword list, e.g.
      `%{explore: :activation}`) merged into the parameters for this choice. Answers
      `%{selected: solution | nil, explored: boolean, candidates: n, died: [solution]}`;
      the problem stays pending (so the candidates stay on the host) until the feedback;
    * `{:feedback, cost}` (a request) - the selected solution's measured cost: every
      candidate of that solution still here takes it into its ζ (`Maths.running_score/4`,
      here the running mean of the domain's cost itself, not relative to other
      candidates, which did not run), the selected iPkt makes NC clones (Eqs.
      6.11-6.13) and dies if it is left below τ_min; the problem is removed. Answers
      `%{executed: solution | nil, born: n, died: [solution]}`.

  The decisions are the pure functions `interact/4`, `choose/3` and `feedback/5`; this
  module only carries them out. Candidates whose activation or score changed are told
  with `{:update, tau, {zeta, n}}`, so the values travel with them.
  """
  use Tartarus.Agent

  alias TartarusImmune.{Cache, Domain, Maths}

  @doc false
  def init(s), do: {:stay, Map.merge(%{queue: %{}, problems: [], choice: nil}, s)}

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

    if s.danger and new != [] and not per_round?(s.p) do
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

    p =
      s.p
      |> Map.put(:q_current, map_size(s.queue))
      |> Map.put(:scale, Domain.score_scale(s.domain, pb.inst))

    case interact(members, pb.fv, score, p) do
      :no_candidates ->
        Tartarus.Agent.reply(from, %{executed: nil, waiting: pb.ref, born: 0, died: []})
        {:stay, s}

      d ->
        host = Tartarus.Agent.host()

        # The other candidates carry their new activation and score away with them.
        for {id, tau} <- d.taus,
            id != d.selected,
            id not in d.dead,
            do: :ok = Tartarus.post({id, host}, {:update, tau, d.scores[id]})

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

  def handle_message(:choose, from, s), do: handle_message({:choose, %{}}, from, s)

  def handle_message({:choose, _over}, from, %{problems: []} = s) do
    Tartarus.Agent.reply(from, %{selected: nil, explored: false, candidates: 0, died: []})
    {:stay, %{s | choice: nil}}
  end

  def handle_message({:choose, over}, from, %{problems: [pb | _]} = s) do
    members = s.queue |> Enum.sort_by(fn {_id, m} -> m.tag end)

    case choose(members, pb.fv, Map.merge(s.p, Map.new(over))) do
      :no_candidates ->
        Tartarus.Agent.reply(from, %{selected: nil, explored: false, candidates: 0, died: []})
        {:stay, %{s | choice: nil}}

      d ->
        host = Tartarus.Agent.host()

        for {id, tau} <- d.taus, id not in d.dead do
          m = s.queue[id]
          :ok = Tartarus.post({id, host}, {:update, tau, {m.zeta, m.n}})
        end

        for id <- d.dead, do: :ok = Tartarus.post({id, host}, :die)

        queue =
          d.taus
          |> Enum.reduce(s.queue, fn {id, t}, q -> put_in(q[id].tau, t) end)
          |> Map.drop(d.dead)

        Tartarus.Agent.reply(from, %{
          selected: d.solution,
          explored: d.explored,
          candidates: length(d.taus),
          died: Enum.map(d.dead, &s.queue[&1].sol)
        })

        {:stay, %{s | queue: queue, choice: %{id: d.selected, sol: d.solution}}}
    end
  end

  def handle_message({:feedback, _cost}, from, %{problems: []} = s) do
    Tartarus.Agent.reply(from, %{executed: nil, born: 0, died: []})
    {:stay, %{s | choice: nil}}
  end

  def handle_message({:feedback, cost}, from, %{problems: [pb | rest]} = s) do
    publish(rest)
    s = %{s | problems: rest}
    choice = s.choice

    if choice == nil or not Map.has_key?(s.queue, choice.id) do
      Tartarus.Agent.reply(from, %{executed: choice && choice.sol, born: 0, died: []})
      {:stay, %{s | choice: nil}}
    else
      kin =
        s.queue
        |> Enum.filter(fn {_, m} ->
          m.sol == choice.sol and Maths.recognizes?(pb.fv, m.fv, s.p)
        end)
        |> Enum.sort_by(fn {_id, m} -> m.tag end)

      sel = {choice.id, s.queue[choice.id]}
      d = feedback(sel, kin, pb.fv, cost, Map.put(s.p, :q_current, map_size(s.queue)))
      host = Tartarus.Agent.host()

      for {id, score} <- d.scores, id != choice.id do
        :ok = Tartarus.post({id, host}, {:update, s.queue[id].tau, score})
      end

      msg =
        if d.nc > 0,
          do: {:clone, d.nc, d.psi_norm, d.tau_after, d.scores[choice.id], clone_tau(s.p)},
          else: {:update, d.tau_after, d.scores[choice.id]}

      :ok = Tartarus.post({choice.id, host}, msg)
      for id <- d.dead, do: :ok = Tartarus.post({id, host}, :die)

      queue =
        d.scores
        |> Enum.reduce(s.queue, fn {id, {z, n}}, q -> update_in(q[id], &%{&1 | zeta: z, n: n}) end)
        |> then(&put_in(&1[choice.id].tau, d.tau_after))
        |> Map.drop(d.dead)

      Tartarus.Agent.reply(from, %{
        executed: choice.sol,
        born: d.nc,
        died: Enum.map(d.dead, &s.queue[&1].sol)
      })

      {:stay, %{s | queue: queue, choice: nil}}
    end
  end

  def handle_message(:queue, from, s) do
    Tartarus.Agent.reply(from, Map.values(s.queue))
    {:stay, s}
  end

  def handle_message({:diffuse, tag}, from, s) do
    fvs =
      if s.danger,
        do:
          danger_call(
            Enum.map(s.problems, & &1.fv),
            Enum.map(s.queue, fn {_, m} -> m.fv end),
            s.p
          ),
        else: nil

    if fvs != nil do
      :ok = Tartarus.Agent.emit_signal({:danger, tag}, s.p.sg_max, span: s.p.l_span, data: fvs)
    end

    Tartarus.Agent.reply(from, fvs != nil)
    {:stay, s}
  end

  def handle_message(:pending, from, s) do
    Tartarus.Agent.reply(from, length(s.problems))
    {:stay, s}
  end

  def handle_message(:served, from, s) do
    fys = s.queue |> Map.values() |> Enum.map(& &1.fv)
    Tartarus.Agent.reply(from, served?(Enum.map(s.problems, & &1.fv), fys, s.p))
    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  @doc false
  def handle_info(_msg, s), do: {:stay, s}

  @doc """
  Whether a host is served: some resident iPkt (F_y in `fys`) recognizes (Eq. 6.7) some
  pending problem (F_x in `fxs`). Pure.

      iex> p = %{mu: 0.5}
      iex> TartarusImmune.Node.served?([[0, 0, 0, 0]], [[1, 1, 1, 1], [0, 0, 0, 1]], p)
      true
      iex> TartarusImmune.Node.served?([[0, 0, 0, 0]], [[1, 1, 1, 1]], p)
      false
      iex> TartarusImmune.Node.served?([], [[0, 0, 0, 0]], p)
      false
  """
  @spec served?([[float()]], [[float()]], map()) :: boolean()
  def served?(fxs, fys, p),
    do: Enum.any?(fxs, fn fx -> Enum.any?(fys, &Maths.recognizes?(fx, &1, p)) end)

  @doc """
  The decisions of one interaction (Algorithm 4, lines 9-21) for a problem of feature
  vector `fx`, pure. `members` are `{id, %{sol:, fv:, tau:, zeta:, n:}}` in queue order;
  `score` gives a solution's cost on the instance; `p` holds the parameters, `:q_current`
  and `:scale` (the instance's `TartarusImmune.Domain.score_scale/2`). Each candidate's
  ζ takes its cost divided by `p.scale` (`p.score_ref == :instance`; a missing `:scale`
  is 1) or by the cheapest candidate's cost (`:best_candidate`).
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

      ref =
        case Map.get(p, :score_ref, :best_candidate) do
          :instance -> Map.get(p, :scale, 1)
          :best_candidate -> costs |> Map.values() |> Enum.min() |> max(1)
        end

      zetas =
        Enum.map(cands, fn {_, m} ->
          Maths.running_score(m.zeta, m.n, costs[m.sol] / ref, p.score_window)
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

  @doc """
  The choice half of a deferred interaction (see the moduledoc), pure: the candidates
  among `members` (`{id, %{sol:, fv:, tau:, zeta:, n:}}` in queue order) for a problem of
  feature vector `fx` are those that recognize it. Those whose solution has been measured
  (`zeta` not nil) interact in one LIN round over the scores ζ they carry; those never
  measured have no score to compare and take no part in it. Which candidate runs depends
  on `p.explore` (absent: `true`):

    * `true` - the earliest **untried** candidate (fewer than `p.n_min` measures, default
      1: never measured) is tried first; else the measured one of largest activation
      after the round (Algorithm 4, line 19);
    * `:activation` - selection by activation over all candidates: the untried candidate
      of largest activation (a new iPkt's τ_init) runs if its activation is at least the
      largest a measured candidate has after the round, else that measured one. So a new
      solution is tried where no measured one has been stimulated above it, and
      exploration fades as winners gain activation;
    * `false` - the measured candidate of largest activation; untried ones only when none
      is measured.

  A measured candidate that falls below τ_min dies (Eq. 6.17) only once it holds at least
  `p.n_min` measures (default 1: at once), so one unlucky run need not kill it. Returns
  `:no_candidates` or `%{taus: [{id, tau}], selected: id, solution: module, dead: [id],
  explored: boolean}` (`taus` only for the measured candidates; `explored`: the selected
  one was untried); the selected one is never among the dead (it is about to run).

      iex> p = TartarusImmune.Params.new!(tau_min: 5)
      iex> ms = [{1, %{sol: :a, fv: [0.2], tau: 10.0, zeta: 1.2}}, {2, %{sol: :b, fv: [0.2], tau: 10.0, zeta: 2.0}}]
      iex> d = TartarusImmune.Node.choose(ms, [0.2], p)
      iex> {d.selected, d.solution, d.taus}
      {1, :a, [{1, 15.0}, {2, 7.0}]}
      iex> new = {3, %{sol: :c, fv: [0.2], tau: 10.0, zeta: nil}}
      iex> d = TartarusImmune.Node.choose(ms ++ [new], [0.2], p)
      iex> {d.selected, d.solution, d.taus, d.explored}
      {3, :c, [{1, 15.0}, {2, 7.0}], true}
      iex> TartarusImmune.Node.choose(ms ++ [new], [0.2], Map.put(p, :explore, :activation)).selected
      1
      iex> TartarusImmune.Node.choose(ms, [0.9], p)
      :no_candidates
  """
  @spec choose([{term(), map()}], [float()], map()) :: :no_candidates | map()
  def choose(members, fx, p) do
    cands = Enum.filter(members, fn {_id, m} -> Maths.recognizes?(fx, m.fv, p) end)
    {measured, never} = Enum.split_with(cands, fn {_id, m} -> m.zeta != nil end)
    n_min = Map.get(p, :n_min, 1)
    untried = Enum.filter(cands, fn {_id, m} -> measures(m) < n_min end)

    if cands == [] do
      :no_candidates
    else
      ms = Enum.map(measured, fn {_, m} -> %{fv: m.fv, tau: m.tau, cost: m.zeta, kind: m.sol} end)
      new = if ms == [], do: [], else: lin(ms, p)
      taus = Enum.zip_with(measured, new, fn {id, _}, n -> {id, n.tau} end)

      best_measured = fn ->
        Enum.at(measured, Maths.select(Enum.zip_with(ms, new, fn m, n -> %{m | tau: n.tau} end)))
      end

      {{sel_id, sel}, explored} =
        case {Map.get(p, :explore, true), untried} do
          {_, _} when measured == [] ->
            {hd(never), true}

          {true, [first | _]} ->
            {first, true}

          {:activation, [_ | _]} ->
            top = new |> Enum.map(& &1.tau) |> Enum.max()
            {id, m} = Enum.max_by(untried, fn {_, m} -> m.tau end)
            if m.tau >= top, do: {{id, m}, true}, else: {best_measured.(), false}

          _ ->
            {best_measured.(), false}
        end

      judged? = fn id -> measures(elem(List.keyfind(cands, id, 0), 1)) >= n_min end
      dead = for {id, t} <- taus, id != sel_id, t < p.tau_min, judged?.(id), do: id
      %{taus: taus, selected: sel_id, solution: sel.sol, dead: dead, explored: explored}
    end
  end

  @doc """
  The feedback half of a deferred interaction, pure: the selected member `{id, m}` ran on
  the problem of features `fx` and cost `cost`; `kin` are the candidates of the same
  solution still on the host (the selected one among them). Each takes the cost into its
  running score; the selected one makes NC clones (Eqs. 6.11-6.13, with `p.q_current`) and
  dies if left below τ_min (Eq. 6.17). Returns `%{scores: %{id => {zeta, n}}, nc:,
  tau_after:, psi_norm:, dead: [id]}`.

      iex> p = TartarusImmune.Params.new!() |> Map.put(:q_current, 1)
      iex> sel = {1, %{sol: :a, fv: [0.5], tau: 20.0, zeta: nil, n: 0}}
      iex> d = TartarusImmune.Node.feedback(sel, [sel], [0.5], 1.5, p)
      iex> {d.scores, d.nc, d.tau_after, d.dead}
      {%{1 => {1.5, 1}}, 3, 5.0, []}
  """
  @spec feedback({term(), map()}, [{term(), map()}], [float()], number(), map()) :: map()
  def feedback({sel_id, sel}, kin, fx, cost, p) do
    kin = if List.keymember?(kin, sel_id, 0), do: kin, else: [{sel_id, sel} | kin]

    scores =
      Map.new(kin, fn {id, m} ->
        {id, Maths.running_score(m.zeta, m.n, cost, p.score_window)}
      end)

    nc = if sel.tau < p.tau_min, do: 0, else: Maths.clones(sel.tau, p.q_current, p)
    tau_after = Maths.after_cloning(sel.tau, nc, p)

    %{
      scores: scores,
      nc: nc,
      tau_after: tau_after,
      psi_norm: Maths.affinity(fx, sel.fv) / Maths.psi_max(length(fx)),
      dead: if(tau_after < p.tau_min, do: [sel_id], else: [])
    }
  end

  @doc """
  Whether a host calls for help this round, pure: with a per-round danger signal
  (`p.signal_life` `:distressed`, `:unserved` or `:unmet`), the feature vectors its danger
  signal carries, or `nil` for no signal. `pending` are the feature vectors of the host's
  pending problems, `residents` those (F_y) of the iPkts in its interaction queue.

    * `:distressed` - the host signals while it has a pending problem (Algorithm 4 diffuses
      danger signals in every iteration of its loop, for the current problems; a solved
      problem calls nobody);
    * `:unserved` - the same, but not while its interaction queue is full (Q_current =
      `length(residents)` >= `p.q_max`): Q_max is "the maximum allowed number of iPkts that
      can enter the interaction site", so a full site has no room for the iPkts a signal
      would bring and no cloning space for them (Eq. 6.12); the call is answered. It
      resumes when the queue drops below Q_max with problems still pending;
    * `:unmet` - only for the pending problems that no resident recognizes (ψ < ψ_th for
      every resident): the danger is a problem the host cannot serve (danger theory: a
      response to damage, not to every antigen); the signal carries just those problems.

  Any other `signal_life` (a signal emitted once per barrage) gives `nil`: no per-round
  signal.

      iex> p = TartarusImmune.Params.new!(signal_life: :unserved, q_max: 5)
      iex> TartarusImmune.Node.danger_call([[0.1, 0.2]], List.duplicate([0.1, 0.2], 4), p)
      [[0.1, 0.2]]
      iex> TartarusImmune.Node.danger_call([[0.1, 0.2]], List.duplicate([0.1, 0.2], 5), p)
      nil
      iex> TartarusImmune.Node.danger_call([], [], p)
      nil
      iex> TartarusImmune.Node.danger_call([[0.1, 0.2]], List.duplicate([0.1, 0.2], 9), %{p | signal_life: :distressed})
      [[0.1, 0.2]]
      iex> p = %{p | signal_life: :unmet}
      iex> TartarusImmune.Node.danger_call([[0.1, 0.2], [1.0, 1.0]], [[0.1, 0.2]], p)
      [[1.0, 1.0]]
      iex> TartarusImmune.Node.danger_call([[0.1, 0.2]], [[0.1, 0.2]], p)
      nil
  """
  @spec danger_call([[float()]], [[float()]], map()) :: [[float()]] | nil
  def danger_call([], _residents, _p), do: nil

  def danger_call(pending, residents, p) do
    case Map.get(p, :signal_life) do
      :distressed ->
        pending

      :unserved ->
        if length(residents) < p.q_max, do: pending

      :unmet ->
        case Enum.reject(pending, fn fx -> Enum.any?(residents, &Maths.recognizes?(fx, &1, p)) end) do
          [] -> nil
          unmet -> unmet
        end

      _ ->
        nil
    end
  end

  @doc """
  True when danger signals are diffused every round by `danger_call/3` (`p.signal_life`
  `:distressed`, `:unserved` or `:unmet`) rather than once per barrage.
  """
  @spec per_round?(map()) :: boolean()
  def per_round?(p), do: Map.get(p, :signal_life) in [:distressed, :unserved, :unmet]

  # how many measures an iPkt's score holds (`n`; without it, 1 once it has a score)
  defp measures(%{n: n}) when is_integer(n), do: n
  defp measures(%{zeta: nil}), do: 0
  defp measures(_m), do: 1

  defp lin(ms, p) do
    if Map.get(p, :lin, :types) == :types,
      do: Maths.interact_types(ms, p),
      else: Maths.interact(ms, p)
  end

  defp clone_tau(%{clone_tau: :tau_min, tau_min: t}), do: t * 1.0
  defp clone_tau(%{clone_tau: t}), do: t * 1.0

  defp publish(problems),
    do: :ok = Tartarus.Agent.store_put(:immune_pending, Enum.map(problems, & &1.fv))
end
