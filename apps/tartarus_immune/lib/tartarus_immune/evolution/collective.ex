defmodule TartarusImmune.Evolution.Collective do
  @moduledoc """
  Several robots learning S3 in one arena and sharing antibodies (thesis §7.4.2, "three
  real robots ... allowed to share their respective IReps"), each robot a host of an
  emulated network (`TartarusEmu.Network`, a full mesh). With `dynamic: p` above 0 the
  mesh's links come and go: every `flap_every` world steps (30, one full evaluation
  period of 3 s) each link breaks, or if broken heals, with probability `p`
  (`TartarusEmu.Dynamics`, as the sharing experiment's links flap), so a broadcast reaches
  only the robots linked at that moment and the packet agent stays where it is when its
  host has no link.

  Every robot runs Algorithm 5 on its own (`TartarusImmune.Evolution.Embodied`'s loop: an
  evaluation period ends when its epitope leaves the antibody's active region, after at
  least `min_period` steps, or after `period`), all in the same world, one 0.1 s step at a
  time. Each robot's host has a keeper (`TartarusImmune.Evolution.Keeper`, a static agent)
  that holds the robot's external repertoire (`XRep`): antibodies shared by the others.
  Every `share_every` iterations a robot publishes its best antibodies (the `share_top` of
  highest concentration, as the thesis allows: "only a set of Abs selected based on a
  fitness criterion can also be shared"), and

    * `:broadcast` - its keeper broadcasts them to the neighbour hosts, whose keepers
      merge them into their XRep;
    * `:ipkt` - they wait in its keeper; one mobile agent (`TartarusImmune.Evolution.AbPkt`)
      visits the hosts conscientiously, one hop each time a robot publishes, leaving the
      antibodies it carries in each keeper's XRep and taking the keeper's published ones;
    * `:none` - nothing is shared.

  A robot picks from its XRep with probability `p_sharing` when a shared antibody matches
  its epitope (`TartarusImmune.Evolution.Repertoire.select/5`); a chosen one is copied into
  its own repertoire and evolves there. After training each robot's repertoire is tested
  like a single robot's.
  """

  alias Tartarus.Clock
  alias TartarusArena.World
  alias TartarusEmu.{Dynamics, Log, Network, Topology}

  alias TartarusImmune.Evolution.{
    AbPkt,
    Courier,
    Embodied,
    ES,
    Keeper,
    NeuralNet,
    Objective,
    Repertoire
  }

  require Tartarus.Clock

  @shape [4, 5, 2]

  @schema [
    robots: [type: :pos_integer, default: 3, doc: "robots"],
    scheme: [
      type: {:in, [:broadcast, :ipkt, :none]},
      default: :broadcast,
      doc: "how antibodies are shared"
    ],
    iterations: [type: :pos_integer, default: 500, doc: "evaluation periods per robot"],
    share_every: [
      type: :pos_integer,
      default: 5,
      doc: "a robot publishes every this many iterations"
    ],
    share_top: [
      type: :pos_integer,
      default: 3,
      doc: "antibodies published (highest concentration)"
    ],
    p_sharing: [
      type: :probability,
      default: 0.2,
      doc: "probability of taking a matching shared antibody"
    ],
    puck_reward: [
      type: {:in, [:product, :sum]},
      default: :product,
      doc:
        "the reading of Eq. 7.2's f_puck: `b_puck * v_trans` or, as printed, `b_puck + v_trans` (`Objective`)"
    ],
    test_episodes: [type: :non_neg_integer, default: 5, doc: "test episodes per robot"],
    dynamic: [
      type: :probability,
      default: 0.0,
      doc: "per tick, the probability that a link breaks (or heals); 0: a static full mesh"
    ],
    flap_every: [
      type: :pos_integer,
      default: 30,
      doc: "world steps (0.1 s) per tick of the links"
    ],
    seed: [type: :integer, default: 1, doc: "seed"]
  ]

  @doc "The options of `run/1`."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Trains the robots on S3 together, then tests each. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, result}` with `test_success` (mean over robots), `per_robot` (antibodies,
  external selections, test success, `publications`, `reached`: robots a publication
  reached by broadcast, `stays`: publications at which the packet agent found no link),
  `communications` (the platform's counters: broadcast messages sent and received,
  hand-offs), `light_switches`, `dynamic`, `link_ticks`, `link_flaps` (links broken or
  healed) and `links_up` (the mean share of links up over the ticks; 1.0 when static).
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "#{inspect(__MODULE__)}.run/1") do
      {:ok, do_run(Map.new(opts))}
    end
  end

  defp do_run(c) do
    o =
      Embodied.options(
        scenario: :s3,
        iterations: c.iterations,
        seed: c.seed,
        test_episodes: c.test_episodes,
        puck_reward: c.puck_reward
      )

    names = for i <- 1..c.robots, do: "r#{i}"
    topo = Topology.new(names, for(a <- names, b <- names, a < b, do: {a, b}))
    {:ok, net} = Network.start(topo)

    try do
      {:ok, log} = Log.start(net)

      keepers =
        Map.new(names, fn n ->
          {:ok, id} = Tartarus.create_static_agent(Network.host(net, n), Keeper, %{})
          {n, id}
        end)

      pkt =
        if c.scheme == :ipkt do
          {:ok, id} =
            Tartarus.create_agent(Network.host(net, hd(names)), AbPkt, %{driver: self()},
              seed: {c.seed, :abpkt}
            )

          id
        end

      switches = Embodied.light_switches(c.iterations, c.seed)
      rng = :rand.seed_s(:exsss, {c.seed, 7, 3})
      {world, rng} = arena(names, c.seed, rng)

      robots =
        Map.new(names, fn n ->
          rep =
            Repertoire.new(
              epsilon: o.epsilon,
              shape: @shape,
              p_sharing: c.p_sharing,
              origin: n,
              es: o.es
            )

          {n, %{rep: rep, done: 0, cur: nil, external: 0, publications: 0, reached: 0, stays: 0}}
        end)

      links = %{
        net: net,
        dyn: Dynamics.new(MapSet.to_list(topo.edges)),
        rng: Dynamics.rng(c.seed),
        steps: 0,
        ticks: 0,
        flaps: 0,
        up: 0.0
      }

      st = %{world: world, rng: rng, robots: robots, links: links}
      st = loop(c, o, st, keepers, pkt, switches, names)
      totals = Log.settled_totals(log)
      Log.stop(log)

      {per, _} =
        Enum.map_reduce(names, st.rng, fn n, rng ->
          r = st.robots[n]
          {success, _, rng} = Embodied.test_repertoire(o, r.rep, rng)

          {%{
             robot: n,
             antibodies: map_size(r.rep.antibodies),
             external_selections: r.external,
             test_success: success,
             publications: r.publications,
             reached: r.reached,
             stays: r.stays
           }, rng}
        end)

      %{
        scheme: c.scheme,
        robots: c.robots,
        test_success: Float.round(Enum.sum(Enum.map(per, & &1.test_success)) / length(per), 3),
        per_robot: per,
        light_switches: Tuple.to_list(switches),
        dynamic: c.dynamic,
        link_ticks: st.links.ticks,
        link_flaps: st.links.flaps,
        links_up:
          if(st.links.ticks > 0, do: Float.round(st.links.up / st.links.ticks, 3), else: 1.0),
        communications:
          Map.new(
            [:broadcast_messages, :broadcasts_received, :departures, :arrivals],
            &{&1, Map.get(totals, &1, 0)}
          )
      }
    after
      Network.stop(net)
    end
  end

  defp arena(names, seed, rng) do
    w = World.new(size: {2.0, 2.0}, seed: {seed, :collective}, light: [on: false])

    {w, rng} = Enum.reduce(names, {w, rng}, fn n, {w, rng} -> place(w, n, rng, 50) end)

    Enum.reduce(1..10, {w, rng}, fn k, {w, rng} ->
      {px, rng} = between(rng, 0.15, 1.85)
      {py, rng} = between(rng, 0.15, 1.85)

      far? =
        Enum.all?(names, fn n ->
          {x, y, _} = World.pose(w, n)
          (px - x) ** 2 + (py - y) ** 2 > 0.04
        end)

      if far? and Embodied.puck_room?(w, px, py),
        do: {World.add_puck(w, k, x: px, y: py), rng},
        else: {w, rng}
    end)
  end

  defp place(w, n, rng, tries) do
    {x, rng} = between(rng, 0.2, 1.8)
    {y, rng} = between(rng, 0.2, 1.8)
    {th, rng} = between(rng, -:math.pi(), :math.pi())

    try do
      {World.add_robot(w, n, x: x, y: y, theta: th, tool: :pusher), rng}
    rescue
      e in ArgumentError ->
        if tries > 0, do: place(w, n, rng, tries - 1), else: reraise(e, __STACKTRACE__)
    end
  end

  defp between(rng, a, b) do
    {u, rng} = :rand.uniform_s(rng)
    {a + (b - a) * u, rng}
  end

  # One world step at a time until every robot has done its iterations.
  defp loop(c, o, st, keepers, pkt, switches, names) do
    if Enum.all?(names, &(st.robots[&1].done >= c.iterations)) do
      st
    else
      lead = st.robots[hd(names)].done + 1

      world =
        World.set_light(st.world, if(Embodied.light_at(:s3, switches, lead), do: :on, else: :off))

      st = %{st | world: world}
      # robots without a period start one
      st = Enum.reduce(names, st, fn n, st -> start(c, o, st, n, keepers) end)

      commands =
        Map.new(names, fn n ->
          case st.robots[n].cur do
            nil -> {n, {0.0, 0.0}}
            cur -> {n, List.to_tuple(NeuralNet.forward(@shape, cur.w, cur.inputs))}
          end
        end)

      world = World.step(st.world, commands, o.dt)
      st = %{st | world: world, links: flap(c, st.links)}
      st = Enum.reduce(names, st, fn n, st -> advance(c, o, st, n, keepers, pkt) end)
      loop(c, o, st, keepers, pkt, switches, names)
    end
  end

  # The links come and go (`dynamic` above 0): a tick every `flap_every` world steps, between
  # two steps (no publication in flight).
  defp flap(%{dynamic: p}, links) when p == 0, do: links

  defp flap(c, links) do
    links = %{links | steps: links.steps + 1}

    if rem(links.steps, c.flap_every) == 0 do
      {events, dyn, rng} = Dynamics.step(links.dyn, c.dynamic, links.rng)

      Enum.each(events, fn
        {:down, {a, b}} -> :ok = Network.break_link(links.net, a, b)
        {:up, {a, b}} -> :ok = Network.heal_link(links.net, a, b)
      end)

      up = 1 - length(Dynamics.down(dyn)) / max(length(dyn.elements), 1)

      %{
        links
        | dyn: dyn,
          rng: rng,
          ticks: links.ticks + 1,
          flaps: links.flaps + length(events),
          up: links.up + up
      }
    else
      links
    end
  end

  defp start(c, _o, st, n, keepers) do
    r = st.robots[n]

    if r.cur != nil or r.done >= c.iterations do
      st
    else
      {readings, world} = World.sense(st.world, n)
      ep = World.normalize(readings)
      {rep, cands, rng} = Repertoire.recognize(r.rep, ep, st.rng)

      {:ok, xrep} =
        if c.scheme == :none, do: {:ok, %{}}, else: Tartarus.request(keepers[n], :xrep)

      xrep = Map.reject(xrep, fn {key, _} -> Map.has_key?(rep.antibodies, key) end)
      {rep, key, from, rng} = Repertoire.select(rep, cands, ep, xrep, rng)
      ab = rep.antibodies[key]
      {kind, w, rng} = ES.propose(ab.es, rng)
      cur = %{key: key, kind: kind, w: w, paratope: ab.paratope, inputs: ep, samples: []}
      r = %{r | rep: rep, cur: cur, external: r.external + if(from == :external, do: 1, else: 0)}
      %{st | world: world, rng: rng, robots: Map.put(st.robots, n, r)}
    end
  end

  defp advance(c, o, st, n, keepers, pkt) do
    r = st.robots[n]

    case r.cur do
      nil ->
        st

      cur ->
        {readings, world} = World.sense(st.world, n)
        ep = World.normalize(readings)
        samples = [Embodied.sample(world, n, readings) | cur.samples]
        k = length(samples)

        over =
          k >= o.period or
            (k >= o.min_period and Repertoire.affinity(ep, cur.paratope) > o.epsilon)

        r =
          if over do
            fitness = Objective.fitness(:s3, samples, puck_reward: c.puck_reward) / k
            ab = r.rep.antibodies[cur.key]
            rep = Repertoire.put_es(r.rep, cur.key, ES.tell(ab.es, {cur.kind, cur.w}, fitness))
            rep = Repertoire.report(rep, cur.key, fitness)
            r = %{r | rep: rep, cur: nil, done: r.done + 1}

            if rem(r.done, c.share_every) == 0,
              do: published(r, publish(c, r, keepers, n, pkt)),
              else: r
          else
            %{r | cur: %{cur | samples: samples, inputs: ep}}
          end

        %{st | world: world, robots: Map.put(st.robots, n, r)}
    end
  end

  defp published(r, {reached, stays}),
    do: %{
      r
      | publications: r.publications + 1,
        reached: r.reached + reached,
        stays: r.stays + stays
    }

  # publishes; returns {robots reached by broadcast, 1 if the packet agent found no link}
  defp publish(%{scheme: :none}, _r, _keepers, _n, _pkt), do: {0, 0}

  defp publish(c, r, keepers, n, pkt) do
    keeper = keepers[n]

    top =
      r.rep.antibodies
      |> Enum.sort_by(fn {key, ab} -> {-ab.concentration, key} end)
      |> Enum.take(c.share_top)
      |> Map.new()

    before = if c.scheme == :broadcast, do: received(keepers), else: 0
    {:ok, sent} = Tartarus.request(keeper, {:publish, top, c.scheme})

    # A broadcast is received a moment after it was sent: wait for it, so that what the
    # other robots select next does not depend on the scheduler.
    if c.scheme == :broadcast, do: await_received(keepers, before + sent, 30_000)

    if c.scheme == :ipkt do
      {:ok, :ok} = Tartarus.request(pkt, :visit, 10_000)

      Clock.receive do
        {:ipkt_moved, ^pkt} -> {0, 0}
        {:ipkt_stayed, ^pkt} -> {0, 1}
      after
        10_000 -> raise "the antibody packet neither moved nor stayed within 10 s"
      end
    else
      {sent, 0}
    end
  end

  defp received(keepers),
    do:
      keepers |> Map.values() |> Enum.map(&elem(Tartarus.request(&1, :received), 1)) |> Enum.sum()

  defp await_received(keepers, target, tries),
    do:
      Courier.await_count(fn -> received(keepers) end, target, tries, "broadcasts of antibodies")
end

defmodule TartarusImmune.Evolution.Keeper do
  @moduledoc """
  A robot host's keeper of shared antibodies (`TartarusImmune.Evolution.Collective`): a
  static agent registered in its host's store under `:keeper`. It holds the external
  repertoire (antibodies received, keyed `{origin, id}`, the latest version of each) and the
  robot's last published antibodies. Requests:

    * `{:publish, antibodies, :broadcast}` - broadcasts them to the neighbour hosts (answers
      the number of neighbours); `{:publish, antibodies, _}` keeps them for a visiting
      packet (answers 0);
    * `:xrep` - the external repertoire;
    * `:received` - how many broadcasts of antibodies it has received;
    * `{:exchange, carried}` - a packet's visit: merges `carried` into the external
      repertoire (the robot's own antibodies excepted) and answers the published ones.
  """
  use Tartarus.Agent

  alias Tartarus.Agent

  @doc false
  @impl true
  def init(_args) do
    Agent.store_put(:keeper, Agent.id())
    :ok = Agent.subscribe_broadcasts()
    {:stay, %{xrep: %{}, own: %{}, received: 0}}
  end

  @doc false
  @impl true
  def handle_message({:publish, abs, :broadcast}, from, s) do
    Agent.reply(from, Agent.broadcast({:antibodies, abs}))
    {:stay, %{s | own: abs}}
  end

  def handle_message({:publish, abs, _}, from, s) do
    Agent.reply(from, 0)
    {:stay, %{s | own: abs}}
  end

  def handle_message(:xrep, from, s) do
    Agent.reply(from, s.xrep)
    {:stay, s}
  end

  def handle_message(:received, from, s) do
    Agent.reply(from, s.received)
    {:stay, s}
  end

  def handle_message({:exchange, carried}, from, s) do
    Agent.reply(from, s.own)
    {:stay, merge(s, carried)}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  @doc false
  @impl true
  def handle_info({:tartarus_broadcast, _from, {:antibodies, abs}}, s),
    do: {:stay, %{merge(s, abs) | received: s.received + 1}}

  def handle_info(_other, s), do: {:stay, s}

  defp merge(s, abs) do
    abs = Map.reject(abs, fn {key, _} -> Map.has_key?(s.own, key) end)
    %{s | xrep: Map.merge(s.xrep, abs)}
  end
end

defmodule TartarusImmune.Evolution.AbPkt do
  @moduledoc """
  A packet of antibodies (an iPkt of `TartarusImmune.Evolution.Collective`): a mobile agent
  that carries the antibodies it collected from keeper to keeper, conscientiously. On
  `:visit` it exchanges with the keeper of its host (leaves what it carries, takes what the
  robot published, the newer version of an antibody winning), answers, and moves on,
  telling the driver `{:ipkt_moved, id}` or `{:ipkt_stayed, id}`.
  """
  use Tartarus.Agent,
    ships: [
      TartarusImmune.Evolution.ES,
      TartarusImmune.Evolution.Repertoire,
      TartarusImmune.Evolution.Courier
    ]

  alias Tartarus.Agent
  alias TartarusImmune.Evolution.Courier

  @doc false
  @impl true
  def init(args), do: {:stay, Map.put(args, :carried, %{})}

  @doc false
  @impl true
  def handle_message(:visit, from, s) do
    s =
      case Agent.store_get(:keeper) do
        nil ->
          s

        keeper ->
          case Tartarus.request(keeper, {:exchange, s.carried}) do
            {:ok, own} -> %{s | carried: Map.merge(s.carried, own)}
            _ -> s
          end
      end

    Agent.reply(from, :ok)
    Courier.hop(s)
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  @doc false
  @impl true
  def handle_arrival(_ctx, s), do: Courier.tell(s, :ipkt_moved)

  @doc false
  @impl true
  def handle_move_failed(_dest, _reason, _ctx, s), do: Courier.tell(s, :ipkt_stayed)
end
