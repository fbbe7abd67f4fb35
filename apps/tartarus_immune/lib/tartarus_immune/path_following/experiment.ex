defmodule TartarusImmune.PathFollowing.Experiment do
  @moduledoc """
  The path-following experiment of thesis §6.5.11 (Fig. 6.13, Table 6.5): two robots on
  Path-1 and Path-2 at once learn which PFA to use on which kind of sub-path with the
  immune selection mechanism (`TartarusImmune.Node`, `TartarusImmune.IPkt`,
  `TartarusImmune.Maths`), sharing what they learn through iPkts (`mix tartarus.pfa`).

  ## One trial

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

  ## Measures

  * `lap_times`: per path, the time of each lap (one list per trial) and the mean over
    trials per lap (Fig. 6.13 a and b);
  * `plateau_lap`: per path, on the mean curve, the first lap L such that every lap from
    L to the last is within 10% of the **final mean** (the mean of the last 3 laps); and
    `plateau_time`, the mean lap time from the plateau lap to the last;
    `plateau_lap_5pct` the same within 5% (on Path-1 the whole fall from a random PFA's
    lap to the best lap is about 14%, so a 10% band often holds from lap 1 or 2);
  * `best_pfa`: per sub-path type, the most frequent best PFA over the trials (ties: the
    earlier PFA), with `best_pfa_counts`;
  * `exhaustive_best`: per type, the PFA of least mean `score/2` over the type's
    instances on both paths (first trial's seed), with every PFA's mean
    (`exhaustive_costs`): the reference of trying everything;
  * `measured_costs`: per type and PFA, the mean normalized cost and the number of runs
    the robots measured in the laps of all trials (what the mechanism learned from), and
    `measured_best`, the PFA of least mean among those run at least 3 times;
  * `sim_speed_x`: simulated seconds (arena time summed over trials) per wall second of
    the trials, the immune network included.

  Choices (all options): μ = 0.8 rather than Table 6.1's 0.5, since with ψ_max = 2 (four
  features) μ = 0.5 lets an iPkt recognize sub-paths of other types (sp-a and sp-c, sp-b
  and sp-d and sp-a and sp-d are 0.67-0.79 apart; instances of one type at most 0.2);
  μ = 0.8 recognizes within 0.4. Q_max = 20 rather than 5, since a robot's host holds the
  iPkts of four sub-path types and up to eight PFAs, not one problem class. `:n_min`
  (default 1) is how many measures a PFA needs on a type before suppression can kill it
  (and until then it counts as untried); 2 was tried against single noisy measures and
  made the curves worse (seeds 1-10, last three laps: Path-1 31.6 s against 26.7 s,
  Path-2 52.2 s against 30.0 s): re-trying the losers costs more than the noise it
  removes.
  """

  alias TartarusArena.{PFAs, Paths, Run}
  alias TartarusEmu.{Network, Topology}
  alias TartarusImmune.{Domain, IPkt, Params, PathFollowing}
  alias TartarusTools.{Report, SVG}

  @schema [
    laps: [type: :pos_integer, default: 12, doc: "laps per robot"],
    trials: [type: :pos_integer, default: 10, doc: "trials (seeds seed, seed + 1, ...)"],
    seed: [type: :integer, default: 1, doc: "seed of the first trial"],
    pfas: [
      type: {:list, :atom},
      default: nil,
      doc: "the PFAs the input stream offers (default all eight)"
    ],
    sharing: [
      type: {:in, [:clones, true, false]},
      default: :clones,
      doc:
        "how mappings travel between the robots: :clones (fresh clones go to the other robot, the rest stay), true (every iPkt not held by a problem moves on), false (none)"
    ],
    explore: [
      type: {:or, [{:in, [:activation, :untried_first]}, :probability]},
      default: :untried_first,
      doc:
        "when a robot tries a PFA not yet measured on the sub-path's type: :activation (if its activation is at least the best measured one's), :untried_first (always, at once), or a probability"
    ],
    n_min: [
      type: :pos_integer,
      default: 1,
      doc: "measures of a PFA on a sub-path type before suppression can kill it"
    ],
    stream: [
      type: {:in, [:once, :lifelong]},
      default: :once,
      doc:
        "the input stream: :once (each PFA once per robot, nothing after the eighth) or :lifelong (then, each lap, one PFA whose mapping of some sub-path type has died out at the robot, for those types)"
    ],
    challenge: [
      type: {:in, [:tried, :activation]},
      default: :tried,
      doc:
        "a re-injected PFA: :tried (enters at tau_max, so it runs once) or :activation (tau_init, as a new one)"
    ],
    stuck_after: [
      type: :number,
      default: 6.0,
      doc:
        "seconds without 5 cm of progress after which the experimenter nudges a robot 10 cm on (Run.laps/3's :stuck_after)"
    ],
    lost_penalty: [
      type: :number,
      default: 5.0,
      doc: "seconds charged each time a robot is put back on the line or nudged on"
    ],
    danger: [type: :boolean, default: true, doc: "danger signals on"],
    exhaustive: [type: :boolean, default: true, doc: "also run the exhaustive search"],
    params: [
      type: :keyword,
      default: [],
      doc: "Table 6.1 parameters (TartarusImmune.Params); defaults here mu 0.8, q_max 20"
    ],
    out: [type: :any, default: nil, doc: "output directory, or false for none"]
  ]

  @thesis %{
    plateau_lap: %{"path1" => 6, "path2" => 8},
    plateau_time: %{"path1" => 22, "path2" => 31}
  }
  @table6_5 %{"sp_a" => "A4", "sp_b" => "A2", "sp_c" => "A1", "sp_d" => "A2"}

  @doc "The options of `run/1` (`Tartarus.Options` schema)."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Runs the trials and writes the outputs (unless `out: false`): `lap_times.csv` (trial,
  path, lap, seconds), `lap_times_trial1.svg` (Fig. 6.13a), `lap_times_mean.svg`
  (Fig. 6.13b), `choices.csv` (every sub-path crossed: trial, robot, lap, index, type,
  PFA, time, on_line, normalized cost), `best_pfa.csv` (Table 6.5 beside the thesis and
  the exhaustive search), `summary.json`, `summary.md`. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, %{summary: map, out: dir | nil, trials: [trial]}}` or `{:error, message}`.
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts \\ []) do
    with {:ok, o} <- Tartarus.Options.validate(opts, @schema, "#{inspect(__MODULE__)}.run/1"),
         o = Map.new(o),
         {:ok, p} <- Params.new(Keyword.merge([mu: 0.8, q_max: 20], o.params)),
         :ok <- check_pfas(o.pfas) do
      o = %{o | pfas: o.pfas || PFAs.all()}
      t0 = System.monotonic_time(:microsecond)
      trials = for t <- 0..(o.trials - 1), do: trial(o, p, o.seed + t)
      wall = (System.monotonic_time(:microsecond) - t0) / 1.0e6
      exhaustive = if o.exhaustive, do: exhaustive(o.pfas, o.seed)
      summary = summarize(o, trials, exhaustive, wall)

      out =
        case o.out do
          false -> nil
          nil -> Report.default_out_dir("pfa")
          dir -> dir
        end

      if out, do: write(out, o, trials, summary)
      {:ok, %{summary: summary, out: out, trials: trials}}
    end
  end

  defp check_pfas(nil), do: :ok

  defp check_pfas(pfas) do
    if pfas != [] and Enum.all?(pfas, &(&1 in PFAs.all())),
      do: :ok,
      else:
        {:error,
         "invalid value for :pfas: expected PFA modules of TartarusArena.PFAs.all(), got: #{inspect(pfas)}"}
  end

  # -- one trial -------------------------------------------------------------------------

  @doc """
  One trial under `seed` (options validated as in `run/1`, `p` the parameters): returns
  `%{seed, lap_times: %{1 => [...], 2 => [...]}, best: %{type => name}, choices, sim_time,
  counters}`.
  """
  @spec trial(map(), map(), integer()) :: map()
  def trial(o, p, seed) do
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

  defp receive_event(run) do
    receive do
      {:immune, ^run, ev, _tag, sol} -> {ev, sol}
    after
      60_000 -> raise "pfa: an iPkt did not answer in 60 s"
    end
  end

  defp live(st) do
    Enum.flat_map(Map.values(st.hosts), fn h ->
      {:ok, q} = Tartarus.request({"immune", h}, :queue)
      q
    end)
  end

  # -- the exhaustive reference --------------------------------------------------------------

  @doc """
  Every PFA of `pfas` over every sub-path instance of both paths under `seed`
  (`PathFollowing.score/2`): per type, `{best_name, %{name => mean normalized cost}}`.
  """
  @spec exhaustive([module()], integer()) :: %{Paths.type() => {String.t(), map()}}
  def exhaustive(pfas, seed) do
    refs = for set <- [:p1, :p2], i <- 0..(PathFollowing.sets()[set] - 1), do: {set, i}

    by_type = Enum.group_by(refs, fn {set, i} -> PathFollowing.instance(set, i, seed).type end)

    Map.new(by_type, fn {type, rs} ->
      {best, means} = Domain.class_best(PathFollowing, pfas, rs, seed)

      {type,
       {PFAs.name(best), Map.new(means, fn {s, m} -> {PFAs.name(s), Float.round(m, 3)} end)}}
    end)
  end

  # -- summary ---------------------------------------------------------------------------

  # per path, over every crossing of every trial: put-backs, nudges, the seconds charged
  # for them, the crossings that had one, and the share of the robot's time those took
  defp failures(trials) do
    rows = Enum.flat_map(trials, & &1.choices)

    Map.new([{:r1, "path1"}, {:r2, "path2"}], fn {robot, key} ->
      rs = Enum.filter(rows, &(&1.robot == robot))
      failed = Enum.filter(rs, &(&1.put_back + &1.nudged > 0))
      total = rs |> Enum.map(& &1.time) |> Enum.sum()

      {key,
       %{
         crossings: length(rs),
         failed_crossings: length(failed),
         put_back: rs |> Enum.map(& &1.put_back) |> Enum.sum(),
         nudged: rs |> Enum.map(& &1.nudged) |> Enum.sum(),
         penalty_seconds: round3(rs |> Enum.map(& &1.penalty) |> Enum.sum()),
         failed_time_share: round3(Enum.sum(Enum.map(failed, & &1.time)) / max(total, 1.0e-9))
       }}
    end)
  end

  @doc """
  The plateau lap of a lap-time curve: the first lap L (1-based) such that every lap from
  L to the last is within `tol` (10%) of the mean of the last `tail` (3) laps.

      iex> TartarusImmune.PathFollowing.Experiment.plateau_lap([60, 40, 31, 29, 30, 30])
      3
      iex> TartarusImmune.PathFollowing.Experiment.plateau_lap([30, 30, 30])
      1
  """
  @spec plateau_lap([number()], number(), pos_integer()) :: pos_integer() | nil
  def plateau_lap(times, tol \\ 0.1, tail \\ 3)
  def plateau_lap([], _tol, _tail), do: nil

  def plateau_lap(times, tol, tail) do
    last = Enum.take(times, -tail)
    final = Enum.sum(last) / length(last)
    n = length(times)

    times
    |> Enum.with_index(1)
    |> Enum.reverse()
    |> Enum.reduce_while(n, fn {t, i}, acc ->
      if abs(t - final) <= tol * final, do: {:cont, i}, else: {:halt, acc}
    end)
  end

  defp summarize(o, trials, exhaustive, wall) do
    paths = [{1, "path1"}, {2, "path2"}]

    per_trial = Map.new(paths, fn {id, key} -> {key, Enum.map(trials, & &1.lap_times[id])} end)

    mean = Map.new(per_trial, fn {key, lists} -> {key, mean_curve(lists)} end)

    plateau = Map.new(mean, fn {k, c} -> {k, plateau_lap(c)} end)

    plateau_time =
      Map.new(mean, fn {k, c} ->
        case plateau[k] do
          nil -> {k, nil}
          l -> {k, round3(avg(Enum.drop(c, l - 1)))}
        end
      end)

    types = Enum.map(Paths.types(), &Atom.to_string/1)

    counts =
      Map.new(Paths.types(), fn type ->
        {Atom.to_string(type),
         trials |> Enum.map(& &1.best[type]) |> Enum.reject(&is_nil/1) |> Enum.frequencies()}
      end)

    order = Enum.map(o.pfas, &PFAs.name/1)

    best =
      Map.new(counts, fn {type, c} ->
        {type,
         case Enum.sort_by(c, fn {name, n} -> {-n, Enum.find_index(order, &(&1 == name))} end) do
           [] -> nil
           [{name, _} | _] -> name
         end}
      end)

    sim = trials |> Enum.map(& &1.sim_time) |> Enum.sum()

    # what the robots measured in the laps, over every trial: type -> PFA -> mean, count
    measured =
      trials
      |> Enum.flat_map(& &1.choices)
      |> Enum.group_by(&Atom.to_string(&1.type))
      |> Map.new(fn {type, rows} ->
        {type,
         rows
         |> Enum.group_by(& &1.pfa)
         |> Map.new(fn {pfa, rs} ->
           {pfa, %{mean: round3(avg(Enum.map(rs, & &1.cost))), runs: length(rs)}}
         end)}
      end)

    measured_best =
      Map.new(measured, fn {type, m} ->
        {type,
         m
         |> Enum.filter(fn {_, v} -> v.runs >= 3 end)
         |> Enum.min_by(fn {_, v} -> v.mean end, fn -> {nil, nil} end)
         |> elem(0)}
      end)

    ex =
      if exhaustive,
        do: Map.new(exhaustive, fn {t, {b, _}} -> {Atom.to_string(t), b} end),
        else: nil

    %{
      trials: o.trials,
      laps: o.laps,
      seed: o.seed,
      pfas: order,
      sharing: o.sharing,
      explore: o.explore,
      n_min: o.n_min,
      stream: o.stream,
      challenge: o.challenge,
      stuck_after: o.stuck_after,
      lost_penalty: o.lost_penalty,
      danger: o.danger,
      lap_times: %{
        "trial1" => Map.new(per_trial, fn {k, l} -> {k, hd(l)} end),
        "mean" => mean,
        "per_trial" => per_trial
      },
      plateau_lap: plateau,
      plateau_time: plateau_time,
      plateau_lap_5pct: Map.new(mean, fn {k, c} -> {k, plateau_lap(c, 0.05)} end),
      plateau_definition:
        "first lap L of the mean curve such that every lap from L on is within 10% of the mean of the last 3 laps",
      plateau_lap_per_trial:
        Map.new(per_trial, fn {k, lists} -> {k, Enum.map(lists, &plateau_lap/1)} end),
      best_pfa: best,
      best_pfa_counts: counts,
      best_pfa_table6_5: @table6_5,
      exhaustive_best: ex,
      exhaustive_costs:
        if(exhaustive, do: Map.new(exhaustive, fn {t, {_, m}} -> {Atom.to_string(t), m} end)),
      matches_exhaustive: if(ex, do: Map.new(types, &{&1, best[&1] == ex[&1]})),
      matches_table6_5: Map.new(types, &{&1, best[&1] == @table6_5[&1]}),
      measured_costs: measured,
      measured_best: measured_best,
      thesis: @thesis,
      lost_per_trial: Map.new(paths, fn {id, key} -> {key, Enum.map(trials, & &1.lost[id])} end),
      failures: failures(trials),
      counters:
        Enum.reduce(trials, %{}, fn t, acc ->
          Map.merge(acc, t.counters, fn _, a, b -> a + b end)
        end),
      sim_seconds: round3(sim),
      wall_seconds: round3(wall),
      sim_speed_x: round3(sim / max(wall, 1.0e-6))
    }
  end

  defp mean_curve(lists) do
    n = lists |> Enum.map(&length/1) |> Enum.min(fn -> 0 end)

    for i <- 0..(n - 1)//1 do
      lists |> Enum.map(&Enum.at(&1, i)) |> avg() |> round3()
    end
  end

  defp avg([]), do: 0.0
  defp avg(xs), do: Enum.sum(xs) / length(xs)
  defp round3(x), do: Float.round(x * 1.0, 3)

  # -- files -----------------------------------------------------------------------------

  defp write(out, o, trials, s) do
    File.mkdir_p!(out)

    Report.write_csv!(
      out,
      "lap_times",
      ["trial", "seed", "path", "lap", "seconds"],
      for(
        {t, k} <- Enum.with_index(trials, 1),
        id <- [1, 2],
        {secs, lap} <- Enum.with_index(t.lap_times[id], 1),
        do: [k, t.seed, id, lap, secs]
      )
    )

    Report.write_csv!(
      out,
      "choices",
      ~w(trial robot lap index type pfa how time on_line cost put_back nudged penalty),
      for(
        {t, k} <- Enum.with_index(trials, 1),
        c <- t.choices,
        do: [
          k,
          c.robot,
          c.lap,
          c.index,
          c.type,
          c.pfa,
          c.how,
          c.time,
          c.on_line,
          c.cost,
          c.put_back,
          c.nudged,
          c.penalty
        ]
      )
    )

    Report.write_csv!(
      out,
      "best_pfa",
      ["type", "best_pfa", "trials_per_pfa", "table6_5", "exhaustive_best"],
      for type <- Enum.map(Paths.types(), &Atom.to_string/1) do
        counts =
          s.best_pfa_counts[type]
          |> Enum.sort()
          |> Enum.map_join(" ", fn {n, c} -> "#{n}:#{c}" end)

        [
          type,
          s.best_pfa[type],
          counts,
          @table6_5[type],
          s.exhaustive_best && s.exhaustive_best[type]
        ]
      end
    )

    curve = fn lists ->
      for {key, label} <- [{"path1", "Path-1"}, {"path2", "Path-2"}] do
        %{
          name: label,
          points: Enum.with_index(lists[key], 1) |> Enum.map(fn {t, i} -> {i, t} end)
        }
      end
    end

    SVG.write!(
      Path.join(out, "lap_times_trial1.svg"),
      SVG.line_chart(curve.(s.lap_times["trial1"]),
        title: "Time per lap, one trial (seed #{o.seed}; Fig. 6.13a)",
        x_label: "lap",
        y_label: "seconds",
        y_min: 0
      )
    )

    SVG.write!(
      Path.join(out, "lap_times_mean.svg"),
      SVG.line_chart(curve.(s.lap_times["mean"]),
        title: "Mean time per lap over #{o.trials} trials (Fig. 6.13b)",
        x_label: "lap",
        y_label: "seconds",
        y_min: 0
      )
    )

    Report.write_summary!(
      out,
      Map.delete(s, :lap_times) |> Map.put(:lap_times_mean, s.lap_times["mean"]),
      title: "Path-following selection (thesis §6.5.11)",
      comparisons: [
        %{metric: "plateau lap, Path-1", ours: s.plateau_lap["path1"], thesis: 6},
        %{metric: "plateau lap, Path-2", ours: s.plateau_lap["path2"], thesis: 8},
        %{metric: "plateau time, Path-1 (s)", ours: s.plateau_time["path1"], thesis: 22},
        %{metric: "plateau time, Path-2 (s)", ours: s.plateau_time["path2"], thesis: 31}
        | for type <- ["sp_a", "sp_b", "sp_c", "sp_d"] do
            %{
              metric: "best PFA #{type}",
              ours: s.best_pfa[type],
              thesis: @table6_5[type],
              note: "exhaustive search here: #{s.exhaustive_best && s.exhaustive_best[type]}"
            }
          end
      ]
    )
  end
end
