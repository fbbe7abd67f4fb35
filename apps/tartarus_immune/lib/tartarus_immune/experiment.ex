defmodule TartarusImmune.Experiment do
  @moduledoc """
  One run of the protocol of thesis §6.5 as a `TartarusEmu.Scenario`, on a
  `TartarusEmu.Network` (virtual hosts or real BEAM nodes).

  ## Setup

  The network's setup hook creates a `TartarusImmune.Node` agent (`"immune"`) on every
  host. A **training pool** of `train` instances and a disjoint **test set** of `test`
  instances are drawn from the data set (seeded). Every host (or, with `seed_hosts: k`, k
  hosts chosen at random, the others starting empty) gets `per_node` iPkts of each
  initial solution, each with F_y the features of a random pool instance (§6.5.2) and
  activation τ_init. On-the-fly additions put one iPkt on every host.

  ## A step

    1. **Barrage** (at step 1 and every `period` steps): `ceil(eta * nodes)` hosts chosen at
       random (the influx rate η; 0.5: "a random half") each get `beta` instances of the
       pool (the barrage size β); each emits its danger signal `{:danger, epoch}` (unless
       the signal is diffused per round, step 5);
    2. **On-the-fly additions** due at this step (`add: [{step, solution}]`): one iPkt of the
       new solution on every host;
    3. **Interaction**: every host solves its oldest pending problem (`TartarusImmune.Node`);
       the step waits for every clone born;
    4. **Churn** (`dynamic: p`, Fig. 6.6): each host breaks off (all its links down,
       `TartarusEmu.Network.isolate/2`) or, if off, reconnects with probability `p`;
    5. **Migration**: with a per-round danger signal (`signal_life: :distressed` or
       `:unserved`, `TartarusImmune.Node.per_round?/1`) every host first decides whether it
       calls for help (`TartarusImmune.Node.danger_call/3`) and diffuses `{:danger, {epoch,
       step}}` if so; then every iPkt is told `{:go, tag, age}` (tag: the barrage's `epoch`,
       or `{epoch, step}` with a per-round signal; age: the fraction of the barrage period
       gone by, for `signal_life: :eq6_5`) and moves, stays or dies
       (`TartarusImmune.IPkt`); the step waits for every one;
    6. the population per solution is recorded (the learning curve) and given to
       `TartarusImmune.Convergence`.

  The run stops when it has converged (`stop: true`) or after `steps`. An on-the-fly
  addition starts a new competition: the convergence tracker starts afresh (earlier
  convergences are kept in the summary's `convergences`; `winner` and `convergence_step`
  are those of the last competition). Then the **test
  phase**: for each test instance the network's choice is the solution with most live
  iPkts that recognize it (ties: larger summed activation, then solution order; if none
  recognizes it, the most populous solution); `test_accuracy` is the fraction where that is
  the oracle's choice among the offered solutions, `test_regret` the mean extra cost over
  the oracle, `test_regret_rel` the mean of extra cost / oracle cost.

  ## Steps and logged events

  A step is one round (the list above); `convergence_step` is in rounds. The summary also
  counts what the thesis's log server recorded (§6.5.1: "events such as sharing,
  executions"): `convergence_events` is the number of migrations to another host plus
  executions (a selected solution run on a problem) up to the end of the convergence
  round, `convergence_events_all` adds clones and deaths; `events_run` and
  `events_all_run` are the same counts at the end of the run.

  ## Options

  See `schema/0` (and `mix tartarus.select --help`); the parameters of Table 6.1 go in
  `params:` (`TartarusImmune.Params`).
  """
  @behaviour TartarusEmu.Scenario

  alias Tartarus.Clock
  alias TartarusEmu.{Network, Topology}
  alias TartarusImmune.{Cache, Convergence, IPkt, Params}
  alias TartarusImmune.Experiment.HeldOut
  alias TartarusDashboard.Panel
  alias TartarusTools.Series

  @schema [
    domain: [type: :atom, default: TartarusImmune.Sorting, doc: "the problem domain"],
    set: [type: :atom, default: :p1, doc: "the data set"],
    nodes: [type: :pos_integer, default: 10, doc: "hosts"],
    topology: [type: {:in, [:grid, :ring, :line]}, default: :grid, doc: "topology"],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "virtual hosts or peers"],
    group: [type: :pos_integer, default: 1, doc: "hosts per BEAM node in peer mode"],
    solutions: [
      type: {:list, :atom},
      default: nil,
      doc: "initial solutions (default: the domain's first four)"
    ],
    add: [type: {:list, :any}, default: [], doc: "on-the-fly additions `[{step, solution}]`"],
    sharing: [type: :boolean, default: true, doc: "iPkts travel (false: every node alone)"],
    danger: [type: :boolean, default: true, doc: "danger signals on"],
    eta: [type: :probability, default: 0.5, doc: "influx rate: fraction of hosts per barrage"],
    beta: [type: :pos_integer, default: 5, doc: "barrage size: instances per host per barrage"],
    period: [type: :pos_integer, default: 10, doc: "steps between barrages"],
    barrages: [
      type: :any,
      default: nil,
      doc:
        "the rounds of the barrages, a list (default nil: round 1 and every `period` rounds); a signal is followed for `period` rounds after its barrage"
    ],
    repeat: [
      type: {:list, :any},
      default: [],
      doc:
        "copies of earlier barrages `[{round, epoch}]`: at `round`, the hosts of barrage `epoch` get its instances again (Fig. 6.3a's secondary response)"
    ],
    reach: [
      type: :boolean,
      default: false,
      doc:
        "measure, for each distressed host of each barrage, the rounds until an iPkt that recognizes one of its pending problems is resident (`TartarusImmune.Node.served?/3`)"
    ],
    train: [type: :pos_integer, default: 200, doc: "training pool size"],
    test: [type: :pos_integer, default: 50, doc: "held-out test instances"],
    per_node: [type: :pos_integer, default: 1, doc: "initial iPkts per solution per host"],
    seed_hosts: [
      type: {:or, [:pos_integer, nil]},
      default: nil,
      doc:
        "hosts that start with the initial iPkts (`per_node` of each solution), chosen at random; the others start empty (default: every host)"
    ],
    share: [type: {:range, 0, 1}, default: 0.9, doc: "convergence: the leader's least share"],
    hold: [type: :pos_integer, default: 30, doc: "convergence: steps the leader must hold"],
    stop: [type: :boolean, default: true, doc: "stop once converged"],
    dynamic: [
      type: :probability,
      default: 0.0,
      doc: "each step each host breaks off (or, if off, reconnects) with this probability"
    ],
    params: [type: :keyword, default: [], doc: "Table 6.1 parameters (TartarusImmune.Params)"],
    panel: [
      type: :any,
      default: nil,
      doc:
        "an ETS table the run publishes itself into, for the web dashboard (`TartarusImmune.Panel`)"
    ],
    label: [type: :any, default: nil, doc: "the run's name on the dashboard"]
  ]

  @doc "The option schema of a run (besides the runner's `seed`, `steps`, `out`, `quiet`)."
  def schema, do: @schema

  @impl true
  def name, do: "immune"

  @impl true
  def title, do: "Immune selection"

  @impl true
  def setup(opts) do
    {given, _} = Map.split(opts, Keyword.keys(@schema))

    with {:ok, o} <-
           Tartarus.Options.validate(Map.to_list(given), @schema, "TartarusImmune.Experiment"),
         {:ok, p} <- Params.new(o[:params]) do
      o = Map.new(o)
      domain = o.domain
      sols = o.solutions || Enum.take(domain.solutions(), 4)
      rng = opts.rng
      run = make_ref()
      Cache.ensure()
      {pool, test, rng} = split(domain, o.set, o.train, o.test, rng)

      node_state = %{domain: domain, p: p, seed: opts.seed, danger: o.danger}

      hook = fn _node, host ->
        Tartarus.create_static_agent(host, TartarusImmune.Node, node_state, name: "immune")
      end

      # a generous hand-off timeout: thousands of iPkts move at once on a loaded machine, and
      # a hand-off that timed out would change the run (the iPkt stays)
      {:ok, net} =
        Network.start(topology(o.topology, o.nodes),
          mode: o.mode,
          group: o.group,
          setup: hook,
          host_opts: [migration_timeout: 60_000]
        )

      hosts = Network.host_list(net)

      Panel.publish(
        o.panel,
        &:ets.insert(&1, {:run, %{net: net, label: o.label, set: o.set, domain: domain}})
      )

      st = %{
        o: o,
        p: p,
        seed: opts.seed,
        run: run,
        net: net,
        hosts: hosts,
        domain: domain,
        pool: pool,
        test_refs: test,
        rng: rng,
        offered: sols,
        pop: Map.new(sols, &{&1, 0}),
        epoch: 0,
        serial: 0,
        conv: Convergence.new(share: o.share, hold: o.hold),
        history: [],
        isolated: MapSet.new(),
        failed_moves: 0,
        toggles: 0,
        series: Series.new(),
        executed: %{},
        exec_regret: [],
        moves: 0,
        born: 0,
        died: 0,
        expired: 0,
        events_at: %{},
        first_step: nil,
        last_step: 0,
        fired: %{},
        last_barrage: 0,
        waiting: %{},
        reach: [],
        initial_pop: %{}
      }

      {homes, st} = initial_hosts(st, o.seed_hosts)
      st = Enum.reduce(sols, st, fn sol, st -> seed_ipkts(st, sol, o.per_node, homes) end)
      {:ok, %{st | initial_pop: st.pop}}
    end
  end

  defp topology(:grid, n) do
    rows = Enum.find(trunc(:math.sqrt(n))..1//-1, &(rem(n, &1) == 0))
    Topology.grid(rows, div(n, rows))
  end

  defp topology(:ring, n), do: Topology.ring(n)
  defp topology(:line, n), do: Topology.line(n)

  defp split(domain, set, train, test, rng) do
    size = domain.sets()[set]
    {picked, rng} = sample(size, min(train + test, size), rng)
    {pool, rest} = Enum.split(picked, min(train, size - 1))
    {Enum.map(pool, &{set, &1}) |> List.to_tuple(), Enum.map(rest, &{set, &1}), rng}
  end

  # k distinct indices of 0..n-1
  defp sample(n, k, rng) do
    Enum.reduce_while(Stream.cycle([nil]), {MapSet.new(), [], rng}, fn _, {seen, acc, rng} ->
      if length(acc) == k do
        {:halt, {Enum.reverse(acc), rng}}
      else
        {i, rng} = :rand.uniform_s(n, rng)
        i = i - 1

        if MapSet.member?(seen, i),
          do: {:cont, {seen, acc, rng}},
          else: {:cont, {MapSet.put(seen, i), [i | acc], rng}}
      end
    end)
    |> case do
      {acc, rng} -> {acc, rng}
    end
  end

  defp pick(st) do
    {i, rng} = :rand.uniform_s(tuple_size(st.pool), st.rng)
    {elem(st.pool, i - 1), %{st | rng: rng}}
  end

  # The hosts that get the initial iPkts: every host, or `k` of them chosen at random (the
  # run's random stream is drawn only then, so runs with every host are unchanged).
  defp initial_hosts(st, nil), do: {st.hosts, st}

  defp initial_hosts(st, k) do
    {picked, rng} = sample(length(st.hosts), min(k, length(st.hosts)), st.rng)
    hosts = List.to_tuple(st.hosts)
    {Enum.map(picked, &elem(hosts, &1)), %{st | rng: rng}}
  end

  defp seed_ipkts(st, sol, per_node, homes \\ nil) do
    Enum.reduce(homes || st.hosts, st, fn host, st ->
      Enum.reduce(1..per_node, st, fn _, st ->
        {{set, i}, st} = pick(st)
        fv = st.domain.features(st.domain.instance(set, i, st.seed))
        serial = st.serial + 1

        {:ok, _} = IPkt.create(host, sol, fv, serial, st)
        %{st | serial: serial, pop: Map.update(st.pop, sol, 1, &(&1 + 1))}
      end)
    end)
  end

  @impl true
  def step(st, k) do
    st = if barrage?(st.o, k), do: barrage(st, k), else: st

    st =
      case List.keyfind(st.o.repeat, k, 0) do
        {^k, epoch} -> refire(st, k, epoch)
        nil -> st
      end

    st =
      Enum.reduce(st.o.add, st, fn
        {^k, sol}, st ->
          # a new solution opens a new competition: convergence is judged afresh
          st = %{st | history: st.history ++ List.wrap(st.conv.converged)}
          st = %{st | conv: Convergence.new(share: st.o.share, hold: st.o.hold)}
          seed_ipkts(%{st | offered: st.offered ++ [sol]}, sol, 1)

        _, st ->
          st
      end)

    st = interact(st, k)
    st = churn(st)
    st = migrate(st)
    st = reached(st, k)
    pop = Map.new(st.pop, fn {s, n} -> {st.domain.solution_name(s), n} end)

    series =
      Enum.reduce(pop, st.series, fn {name, n}, ser -> Series.record(ser, name, k, n) end)
      |> Series.record("total", k, pop |> Map.values() |> Enum.sum())

    conv = Convergence.observe(st.conv, k, pop)
    Panel.publish(st.o.panel, &:ets.insert(&1, {:round, k, pop, conv.converged}))

    %{
      st
      | series: series,
        conv: conv,
        last_step: k,
        events_at: Map.put(st.events_at, k, log_count(st))
    }
  end

  # What a log server of §6.5.1 would have counted by now: sharing (iPkt migrations to
  # another host) and executions (a selected solution run on a problem, Algorithm 4
  # line 20), and, as a wider variant, every clone and death too.
  defp log_count(st) do
    execs = st.executed |> Map.values() |> Enum.sum()
    {st.moves + execs, st.moves + execs + st.born + st.died + st.expired}
  end

  @impl true
  def done?(st, _k), do: st.o.stop and st.conv.converged != nil

  defp barrage?(%{barrages: nil, period: period}, k), do: k == 1 or rem(k - 1, period) == 0
  defp barrage?(%{barrages: ks}, k), do: k in ks

  defp barrage(st, k) do
    n = length(st.hosts)
    want = min(n, max(1, ceil(st.o.eta * n)))

    {order, rng} =
      Enum.map_reduce(st.hosts, st.rng, fn h, r ->
        {u, r} = :rand.uniform_s(r)
        {{u, h}, r}
      end)

    chosen = order |> Enum.sort() |> Enum.take(want) |> Enum.map(&elem(&1, 1))
    st = %{st | rng: rng, epoch: st.epoch + 1}

    {fired, st} =
      Enum.map_reduce(chosen, st, fn host, st ->
        {refs, st} = Enum.map_reduce(1..st.o.beta, st, fn _, st -> pick(st) end)
        {{host, refs}, st}
      end)

    fire(st, k, fired)
  end

  # Fig. 6.3a's secondary response: barrage `epoch`'s instances again, at the same hosts
  defp refire(st, k, epoch), do: fire(%{st | epoch: st.epoch + 1}, k, Map.fetch!(st.fired, epoch))

  defp fire(st, k, fired) do
    for {host, refs} <- fired,
        do: {:ok, :ok} = Tartarus.request({"immune", host}, {:problems, refs, st.epoch})

    settle(st)
    st = %{st | fired: Map.put(st.fired, st.epoch, fired), last_barrage: k}
    if st.o.reach, do: await_reach(st, k, Enum.map(fired, &elem(&1, 0))), else: st
  end

  # `reach:` a distressed host waits from its barrage (round b) until an iPkt that recognizes
  # one of its pending problems is resident: 0 if one is there when the barrage comes,
  # else the number of migration phases (the one of round b is the first). A host hit again
  # before it was served is censored (`{:censored, rounds}`), as is one at the run's end.
  defp await_reach(st, k, hosts) do
    st =
      Enum.reduce(hosts, st, fn h, st ->
        case Map.pop(st.waiting, h) do
          {nil, _} -> st
          {b, w} -> %{st | waiting: w, reach: [{:censored, k - b} | st.reach]}
        end
      end)

    st = %{st | waiting: Enum.reduce(hosts, st.waiting, &Map.put(&2, &1, k))}
    check_reach(st, fn b -> k - b end)
  end

  defp reached(%{o: %{reach: false}} = st, _k), do: st
  defp reached(st, k), do: check_reach(st, fn b -> k - b + 1 end)

  defp check_reach(st, time) do
    Enum.reduce(st.waiting, st, fn {h, b}, st ->
      {:ok, served?} = Tartarus.request({"immune", h}, :served)

      if served?,
        do: %{st | waiting: Map.delete(st.waiting, h), reach: [time.(b) | st.reach]},
        else: st
    end)
  end

  defp settle(st) do
    if st.o.mode == :peer do
      nodes = st.net |> Network.hosts_by_node() |> Enum.map(&elem(&1, 0))

      for _ <- 1..3 do
        :erpc.multicall(nodes, Tartarus.Signal, :settle, [], 60_000)
        Clock.sleep(20)
      end
    end

    :ok = Tartarus.Signal.settle()
  end

  defp interact(st, _k) do
    reports =
      st.hosts
      |> Task.async_stream(
        fn host ->
          {:ok, r} = Tartarus.request({"immune", host}, :interact, 120_000)
          r
        end,
        timeout: :infinity,
        max_concurrency: System.schedulers_online() * 2
      )
      |> Enum.map(fn {:ok, r} -> r end)

    born = reports |> Enum.map(& &1.born) |> Enum.sum()
    # each ordered clone answers once: born, or its clone action failed (the parent says so)
    events = for _ <- 1..born//1, do: receive_event(st.run, [:born, :move_failed])
    born_sols = Enum.filter(events, &match?({:born, _}, &1))
    born = length(born_sols)

    died = Enum.flat_map(reports, & &1.died)

    pop =
      Enum.reduce(born_sols, st.pop, fn {_, sol}, pop -> Map.update(pop, sol, 1, &(&1 + 1)) end)

    pop = Enum.reduce(died, pop, fn sol, pop -> Map.update!(pop, sol, &(&1 - 1)) end)

    executed =
      Enum.reduce(reports, st.executed, fn
        %{executed: nil}, acc -> acc
        %{executed: sol}, acc -> Map.update(acc, sol, 1, &(&1 + 1))
      end)

    %{st | pop: pop, executed: executed, born: st.born + born, died: st.died + length(died)}
  end

  # Fig. 6.6's dynamic network: between the interaction and the migration phase (no move
  # in flight), each host breaks off or reconnects with probability `dynamic`.
  defp churn(%{o: %{dynamic: p}} = st) when p == 0, do: st

  defp churn(st) do
    Enum.reduce(st.net.topology.nodes, st, fn n, st ->
      {u, rng} = :rand.uniform_s(st.rng)
      st = %{st | rng: rng}

      cond do
        u >= st.o.dynamic ->
          st

        MapSet.member?(st.isolated, n) ->
          Network.rejoin(st.net, n)
          %{st | isolated: MapSet.delete(st.isolated, n), toggles: st.toggles + 1}

        true ->
          Network.isolate(st.net, n)
          %{st | isolated: MapSet.put(st.isolated, n), toggles: st.toggles + 1}
      end
    end)
  end

  defp migrate(st) do
    alive = st.pop |> Map.values() |> Enum.sum()
    # how far into its barrage period the step is (Eq. 6.5's lifetimes, `signal_life:`)
    # (this round is st.last_step + 1)
    age = (st.last_step - st.last_barrage + 1) / st.o.period
    Network.broadcast(st.net, {:go, diffuse(st, age), age})

    Enum.reduce(1..alive//1, st, fn _, st ->
      case receive_event(st.run, [:arrived, :stayed, :expired]) do
        {:arrived, _} ->
          %{st | moves: st.moves + 1}

        {:stayed, _} ->
          st

        {:move_failed, _} ->
          %{st | failed_moves: st.failed_moves + 1}

        {:expired, sol} ->
          %{st | pop: Map.update!(st.pop, sol, &(&1 - 1)), expired: st.expired + 1}
      end
    end)
  end

  # The name's tag of the danger field the iPkts follow this round: the barrage's epoch, or
  # with a per-round signal (`Node.per_round?/1`) a fresh `{epoch, round}`, diffused now by
  # every host that calls for help (`Node.danger_call/3`), after this round's interactions.
  defp diffuse(st, age) do
    cond do
      st.o.danger and TartarusImmune.Node.per_round?(st.p) -> diffuse_round(st)
      # a barrage's signal is followed for its period (only a schedule of barrages further
      # apart than `period` outlives it): then no field is named
      age >= 1 -> {:quiet, st.epoch}
      true -> st.epoch
    end
  end

  defp diffuse_round(st) do
    tag = {st.epoch, st.last_step + 1}

    st.hosts
    |> Task.async_stream(
      fn host -> {:ok, _} = Tartarus.request({"immune", host}, {:diffuse, tag}, 120_000) end,
      timeout: :infinity,
      max_concurrency: System.schedulers_online() * 2
    )
    |> Stream.run()

    settle(st)
    tag
  end

  # births come only in the interaction phase, the rest only in the migration phase
  defp receive_event(run, events),
    do: IPkt.next_event(run, 120_000, "immune: no #{inspect(events)} in 120 s")

  # -- results -------------------------------------------------------------------------

  @impl true
  def series(st), do: st.series

  @impl true
  def summary(st) do
    live = live_ipkts(st)
    t = HeldOut.test(st, live)
    names = fn m -> Map.new(m, fn {s, v} -> {st.domain.solution_name(s), v} end) end

    {winner, conv_step} =
      case st.conv.converged do
        {k, w} -> {w, k}
        nil -> {Convergence.leader(names.(st.pop), 0.0), nil}
      end

    {events_run, events_all_run} = Map.get(st.events_at, st.last_step, {0, 0})
    {conv_events, conv_events_all} = Map.get(st.events_at, conv_step, {nil, nil})

    %{
      set: st.o.set,
      domain: st.domain.name(),
      nodes: length(st.hosts),
      mode: st.o.mode,
      sharing: st.o.sharing,
      danger: st.o.danger,
      winner: winner,
      converged: st.conv.converged != nil,
      convergence_step: conv_step,
      convergences:
        Enum.map(st.history ++ List.wrap(st.conv.converged), fn {k, w} ->
          %{step: k, winner: w}
        end),
      steps_run: st.last_step,
      convergence_events: conv_events,
      convergence_events_all: conv_events_all,
      events_run: events_run,
      events_all_run: events_all_run,
      known_best: t.known_best,
      test_accuracy: t.accuracy,
      test_regret: t.regret,
      test_regret_rel: t.regret_rel,
      test_choices: t.choices,
      population: names.(st.pop),
      live_ipkts: length(live),
      executed: names.(st.executed),
      migrations: st.moves,
      failed_moves: st.failed_moves,
      clones: st.born,
      deaths: st.died,
      expired: st.expired,
      dynamic: st.o.dynamic,
      link_toggles: st.toggles,
      initial_population: names.(st.initial_pop),
      # per barrage (epoch order) a digest of its hosts and instances: a copy (`repeat:`)
      # has the digest of the barrage it copies
      barrage_digests: barrage_digests(st),
      reach: reach_summary(st)
    }
  end

  defp barrage_digests(st) do
    index = st.hosts |> Enum.with_index() |> Map.new()

    for {_epoch, fired} <- Enum.sort(st.fired),
        do: :erlang.phash2(Enum.map(fired, fn {h, refs} -> {index[h], refs} end))
  end

  # `reach:` the waiting times (rounds) of the distressed hosts that were served, and the
  # censored ones (hit again, or still waiting at the end: the rounds they had waited)
  defp reach_summary(%{o: %{reach: false}}), do: nil

  defp reach_summary(st) do
    open = for {_h, b} <- st.waiting, do: {:censored, st.last_step - b + 1}
    {cens, times} = Enum.split_with(st.reach ++ open, &match?({:censored, _}, &1))
    %{times: Enum.reverse(times), censored: Enum.map(cens, &elem(&1, 1))}
  end

  defp live_ipkts(st) do
    Enum.flat_map(st.hosts, fn h ->
      {:ok, q} = Tartarus.request({"immune", h}, :queue)
      q
    end)
  end

  @doc "See `TartarusImmune.Experiment.HeldOut.choose/4`."
  defdelegate choose(live, fx, p, order), to: TartarusImmune.Experiment.HeldOut

  @impl true
  def teardown(st) do
    TartarusImmune.Panel.clear(st.o.panel)
    Network.stop(st.net)
  end
end
