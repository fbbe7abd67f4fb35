defmodule TartarusImmune.PathFollowing.Experiment.Trial do
  @moduledoc """
  One trial of the path-following experiment (`TartarusImmune.PathFollowing.Experiment`,
  thesis §6.5.11): two robots on Path-1 and Path-2 at once, each robot's host a host of
  an emulated network with the immune node on it, the immune mechanism behind the
  `:policy` of `TartarusArena.Run.laps/3`. The experiment runs one trial per seed
  through `TartarusEmu.Sweep`; `TartarusImmune.PathFollowing.Experiment.Summary` sums
  the trials up.

  * The world: both paths of `TartarusArena.Paths` under the trial's seed, robot `r1` on
    Path-1's flag and `r2` on Path-2's, driven together by `TartarusArena.Run.laps/3`.
  * The network: each robot's host is a host of an emulated network
    (`TartarusEmu.Network`, the two hosts linked), with a `TartarusImmune.Node` agent
    (`"immune"`) on each; the domain is `TartarusImmune.PathFollowing`.
  * **Injection** (the thesis's input stream): before lap 1 and at the end of every lap
    but the last, each robot receives one PFA it has not received before, drawn at random
    from the offered PFAs (none once it has had them all, unless `stream: :lifelong`):
    one iPkt of that PFA per
    sub-path type on the robot's map (its path), mapping the PFA to that type's features
    on the map (F_y), activation τ_init, never measured.
  * **Encounter** (the `:policy` of `Run.laps/3`, asked when a robot enters a sub-path):
    the robot's host registers the sub-path as its pending problem and emits the danger
    signal `{:danger, epoch}` carrying its features (a fresh epoch per encounter); one
    migration round follows (every iPkt is told `{:go, epoch}`, see sharing below); then
    the node's `{:choose, %{explore: ...}}` runs the localized idiotypic network over the
    candidates (IRep and XRep alike) and the robot runs the selected PFA
    (`TartarusImmune.Node.choose/3`). If no iPkt recognizes the sub-path the robot keeps
    its current PFA (counted as `no_candidate`; with the default sharing it does not
    happen).
  * **Exploration** (`:explore`): a PFA not yet measured on the sub-path's type (a fresh
    iPkt of the input stream: no score ζ, activation τ_init) takes no part in the LIN
    round. With `:untried_first` (the default) it runs at the first crossing it can, so
    every PFA the stream brings is run once on every type of the robot's map, as the
    thesis's robots executed the PFAs they received; laps 1-8 are then mostly
    exploration and from lap 9 on only the network's choices run. With `:activation` it
    runs when its activation is at least the largest activation a measured candidate has
    after the round (Algorithm 4's "select the iPkt of largest activation" over every
    candidate, the new one entering with τ_init): exploration fades as winners are
    stimulated, but a mapping whose rivals died is never challenged again however badly
    it does (with no measured rival on the robot it is neither stimulated nor
    suppressed, and only `r2` meets sp-d), so some trials kept a PFA failing on every
    crossing to the last lap. A number is a probability per crossing.
  * **Feedback** (told when the robot leaves the sub-path): the measured cost
    (`time * (2 - on_line)`, time including any put-back penalty, over the sub-path's
    nominal time: `TartarusImmune.PathFollowing.normalize/2`) goes to the node
    (`{:feedback, cost}`): the iPkts of the selected PFA take it into their ζ and the
    selected one clones (Eqs. 6.11-6.13). A crossing where the robot lost the line is
    scored like any other: its time includes the penalty (`Run.laps/3` puts a robot 25 cm
    off the line, or one that rejoined it more than 0.15 m further on, back at its
    progress, and nudges one stuck `:stuck_after` seconds, default 6, 10 cm on; each
    costs `:lost_penalty`, default 5 s), so it costs about 2-7 where a clean crossing
    costs 1.0-1.4. 6 s rather than `Run`'s 15: of the stalls that ended by themselves
    (seeds 1-10) 99% ended within 2 s and every working corner manoeuvre within 4.5 s;
    the longer ones were A8 spinning out of reach of the line and A6 circling, at 20 s a
    nudge with 15.
  * **Stream** (`:stream`): `:once` (the default) gives each robot each PFA once;
    `:lifelong` then injects, each lap, a PFA whose mapping of some type has died out at
    the robot, for those types (with `challenge: :tried` at τ_max, so it runs even under
    `explore: :activation`). Measured, re-injection costs more than it saves (the PFAs
    that died mostly died for failing; seeds 1-10, laps 10-12, Path-2 46-51 s against
    28-32 s).
  * **Sharing** (`:sharing`): with `:clones` (the default), as in the thesis ("the
    mapping information and the performance measure of the best PFA is packed into an
    iPkt, cloned and shared with the other robot(s)"), a fresh clone makes one move (up a
    danger signal it recognizes, else conscientiously: between two robots, to the other
    one) and every other iPkt stays in the repertoire of the robot where it is. With
    `true` (roaming, the first version) every iPkt not held by a problem pending at its
    host moves on at each round, so a robot's repertoire drifts to the other robot and
    the iPkts of a type sit pinned at whichever robot is on such a sub-path: seeds 1-10
    had 224 of 1,080 crossings with no candidate, where the robot ran the PFA it had
    chosen for the previous, different sub-path. `false`: nothing moves.

  At the end of a trial the **best PFA per sub-path type** is the network's choice for
  Table 6.3's feature vector of the type (`TartarusImmune.Experiment.choose/4`: the PFA
  with most live iPkts recognizing it, ties by summed activation).
  """

  alias TartarusArena.{PFAs, Paths, Run}
  alias TartarusEmu.{Network, Topology}
  alias TartarusImmune.{IPkt, PathFollowing}

  @doc """
  One trial under `seed` (`o` the options validated by
  `TartarusImmune.PathFollowing.Experiment.run/1`, as a map with `:pfas` set; `p` the
  parameters, `TartarusImmune.Params`): returns `%{seed, lap_times: %{1 => [...], 2 =>
  [...]}, lost: %{1 => n, 2 => n}, best: %{type => name}, choices, sim_time, received,
  population, counters}`. `choices` has a row per sub-path crossed: `robot, lap, index,
  type, pfa, how` (`"explored"`, `"network"` or `"kept"`), `time, on_line, cost,
  put_back, nudged, penalty`.
  """
  @spec run(map(), map(), integer()) :: map()
  def run(o, p, seed) do
    paths = %{r1: PathFollowing.path(1, seed), r2: PathFollowing.path(2, seed)}
    node_state = %{domain: PathFollowing, p: p, seed: seed, danger: o.danger}

    hook = fn _node, host ->
      Tartarus.create_static_agent(host, TartarusImmune.Node, node_state, name: "immune")
    end

    {:ok, net} =
      Network.start(Topology.new(["r1", "r2"], [{"r1", "r2"}]),
        setup: hook,
        host_opts: [migration_timeout: 60_000]
      )

    try do
      st = %{
        o: o,
        p: p,
        seed: seed,
        run: make_ref(),
        net: net,
        paths: paths,
        hosts: %{r1: Network.host(net, "r1"), r2: Network.host(net, "r2")},
        rng: :rand.seed_s(:exsss, {seed, 6_5_11, 13}),
        xrng: :rand.seed_s(:exsss, {seed, 6_5_11, 14}),
        received: %{r1: [], r2: []},
        current: %{r1: nil, r2: nil},
        how: %{r1: nil, r2: nil},
        laps_done: %{r1: 0, r2: 0},
        pop: %{},
        serial: 0,
        epoch: 0,
        choices: [],
        counters: %{
          injected: 0,
          born: 0,
          died: 0,
          expired: 0,
          migrations: 0,
          failed_moves: 0,
          no_candidate: 0,
          reinjected: 0
        }
      }

      st = st |> inject(:r1) |> inject(:r2)
      world = Run.arena([{:r1, paths.r1, 0.0}, {:r2, paths.r2, 0.0}], seed: {seed, :pfa})

      res =
        Run.laps([%{robot: :r1, path: paths.r1}, %{robot: :r2, path: paths.r2}], world,
          laps: o.laps,
          max_time: 120.0 * o.laps,
          stuck_after: o.stuck_after,
          lost_penalty: o.lost_penalty,
          policy: &policy/2,
          policy_state: st
        )

      st = res.policy_state
      live = live(st)

      best =
        Map.new(Paths.types(), fn type ->
          fx = Paths.table_features(type)
          rec = Enum.filter(live, &TartarusImmune.Maths.recognizes?(fx, &1.fv, p))

          {type,
           if(rec == [],
             do: nil,
             else: PFAs.name(TartarusImmune.Experiment.choose(rec, fx, p, o.pfas))
           )}
        end)

      %{
        seed: seed,
        lap_times: %{1 => res.robots.r1.lap_times, 2 => res.robots.r2.lap_times},
        lost: %{1 => res.robots.r1.lost, 2 => res.robots.r2.lost},
        best: best,
        choices: Enum.reverse(st.choices),
        sim_time: res.time,
        received:
          Map.new(st.received, fn {r, l} -> {r, Enum.map(Enum.reverse(l), &PFAs.name/1)} end),
        population: Map.new(st.pop, fn {s, n} -> {PFAs.name(s), n} end),
        counters: st.counters
      }
    after
      Network.stop(net)
    end
  end

  @doc false
  # the policy of Run.laps/3: the immune mechanism behind one function
  def policy({:choose, robot, sp}, st) do
    host = st.hosts[robot]
    epoch = st.epoch + 1
    set = PathFollowing.set_of(st.paths[robot].id)
    {:ok, :ok} = Tartarus.request({"immune", host}, {:problems, [{set, sp.index}], epoch})
    :ok = Tartarus.Signal.settle()
    st = migrate(%{st | epoch: epoch})
    {explore?, st} = explore?(st)

    {:ok, r} =
      Tartarus.request({"immune", host}, {:choose, %{explore: explore?, n_min: st.o.n_min}})

    st = died(st, r.died)

    {pfa, st} =
      case r.selected do
        nil ->
          fallback = st.current[robot] || hd(st.received[robot])
          {fallback, bump(st, :no_candidate, 1) |> put_in([:how, robot], "kept")}

        pfa ->
          {pfa, put_in(st.how[robot], if(r.explored, do: "explored", else: "network"))}
      end

    {pfa, put_in(st.current[robot], pfa)}
  end

  def policy({:result, robot, m}, st) do
    inst = PathFollowing.instance(PathFollowing.set_of(m.path), m.index, st.seed)
    cost = PathFollowing.normalize(m.cost, inst)
    {:ok, r} = Tartarus.request({"immune", st.hosts[robot]}, {:feedback, cost})
    st = born(st, r.born) |> died(r.died)

    row = %{
      robot: robot,
      # the lap event of a lap's last sub-path comes before its result
      lap:
        st.laps_done[robot] + if(m.index == length(st.paths[robot].subpaths) - 1, do: 0, else: 1),
      index: m.index,
      type: m.type,
      pfa: m.pfa,
      time: m.time,
      put_back: Map.get(m, :put_back, 0),
      nudged: Map.get(m, :nudged, 0),
      penalty: Map.get(m, :penalty, 0.0),
      on_line: m.on_line,
      cost: cost,
      how: st.how[robot]
    }

    %{st | choices: [row | st.choices]}
  end

  def policy({:lap, robot, n, _secs}, st) do
    st = put_in(st.laps_done[robot], n)
    if n < st.o.laps, do: inject(st, robot), else: st
  end

  # the node's exploration policy for this encounter (Node.choose/3's p.explore); a
  # probability is a coin thrown from the trial's own exploration stream, so the input
  # stream's draws do not depend on it
  defp explore?(%{o: %{explore: :activation}} = st), do: {:activation, st}
  defp explore?(%{o: %{explore: :untried_first}} = st), do: {true, st}

  defp explore?(st) do
    {x, xrng} = :rand.uniform_s(st.xrng)
    {x < st.o.explore, %{st | xrng: xrng}}
  end

  # one new PFA for `robot`: one iPkt per sub-path type of its map; once every PFA has
  # been received, with stream: :lifelong, one PFA whose mapping of some type of the map
  # has died out in the robot's repertoire, for those types
  defp inject(st, robot) do
    left = st.o.pfas -- st.received[robot]
    types = Enum.uniq_by(st.paths[robot].subpaths, & &1.type)

    cond do
      left != [] ->
        {i, rng} = :rand.uniform_s(length(left), st.rng)
        pfa = Enum.at(left, i - 1)
        st = %{st | rng: rng, received: Map.update!(st.received, robot, &[pfa | &1])}
        Enum.reduce(types, st, &create(&2, robot, pfa, &1.features))

      st.o.stream == :lifelong ->
        reinject(st, robot, types)

      true ->
        st
    end
  end

  defp reinject(st, robot, types) do
    p0 = st.p
    {:ok, q} = Tartarus.request({"immune", st.hosts[robot]}, :queue)

    extinct =
      for pfa <- st.o.pfas,
          sp <- types,
          not Enum.any?(
            q,
            &(&1.sol == pfa and TartarusImmune.Maths.recognizes?(sp.features, &1.fv, st.p))
          ),
          do: {pfa, sp}

    case extinct |> Enum.map(&elem(&1, 0)) |> Enum.uniq() do
      [] ->
        st

      pfas ->
        {i, rng} = :rand.uniform_s(length(pfas), st.rng)
        pfa = Enum.at(pfas, i - 1)

        tau = if st.o.challenge == :tried, do: st.p.tau_max, else: st.p.tau_init
        st = %{st | rng: rng, p: %{st.p | tau_init: tau}}

        for({^pfa, sp} <- extinct, do: sp)
        |> Enum.reduce(st, &create(&2, robot, pfa, &1.features))
        |> Map.put(:p, %{st.p | tau_init: p0.tau_init})
        |> bump(:reinjected, 1)
    end
  end

  defp create(st, robot, pfa, features) do
    serial = st.serial + 1
    {:ok, _} = IPkt.create(st.hosts[robot], pfa, features, serial, st)

    %{st | serial: serial, pop: Map.update(st.pop, pfa, 1, &(&1 + 1))}
    |> bump(:injected, 1)
  end

  defp migrate(st) do
    alive = st.pop |> Map.values() |> Enum.sum()
    Network.broadcast(st.net, {:go, st.epoch})

    Enum.reduce(1..alive//1, st, fn _, st ->
      case receive_event(st.run) do
        {:arrived, _} -> bump(st, :migrations, 1)
        {:stayed, _} -> st
        {:move_failed, _} -> bump(st, :failed_moves, 1)
        {:expired, sol} -> %{bump(st, :expired, 1) | pop: Map.update!(st.pop, sol, &(&1 - 1))}
      end
    end)
  end

  defp born(st, n) do
    Enum.reduce(1..n//1, st, fn _, st ->
      case receive_event(st.run) do
        {:born, sol} -> %{bump(st, :born, 1) | pop: Map.update(st.pop, sol, 1, &(&1 + 1))}
        {:move_failed, _} -> bump(st, :failed_moves, 1)
      end
    end)
  end

  defp died(st, sols) do
    pop = Enum.reduce(sols, st.pop, fn sol, pop -> Map.update!(pop, sol, &(&1 - 1)) end)
    %{bump(st, :died, length(sols)) | pop: pop}
  end

  defp bump(st, key, n), do: update_in(st.counters[key], &(&1 + n))

  defp receive_event(run), do: IPkt.next_event(run, 60_000, "pfa: an iPkt did not answer in 60 s")

  defp live(st) do
    Enum.flat_map(Map.values(st.hosts), fn h ->
      {:ok, q} = Tartarus.request({"immune", h}, :queue)
      q
    end)
  end
end
