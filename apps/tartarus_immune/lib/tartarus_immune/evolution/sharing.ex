defmodule TartarusImmune.Evolution.Sharing do
  @moduledoc """
  One run of the sharing experiment of thesis §7.4.3: robot nodes on a dynamic network
  each evolve a controller for the OR-gate task (`TartarusImmune.Evolution.OrGate`, one
  (1+1)-online evaluation per iteration) and share what they find, either

    * `:broadcast` - social learning: every iteration each node broadcasts its champion to
      its current neighbours (`Tartarus.Agent.broadcast/1`), and each node adopts the best
      one it received if it beats its own;
    * `:ipkt` - `ipkts` intelligent packets (`TartarusImmune.Evolution.IPkt`, mobile agents)
      carry the best controller they met from node to node, conscientiously, one hop per
      iteration, each hop preceded by a small `:hello` broadcast (neighbour discovery, as in
      the thesis);
    * `:none` - no sharing (the baseline).

  ## The network

  `nodes` nodes, each with up to `degree` (5) potential neighbours (a random pairing of
  `degree` link "stubs" per node; `topology/3`). Each link flaps as a two-state Markov
  chain (`TartarusEmu.Dynamics`, probability `p` per iteration both ways): every link
  starts up and half are down in the long run, so a node has between 0 (isolated) and 5
  neighbours and they change at random, as in the thesis. `degree` is the density knob of
  the `density` experiment (`TartarusImmune.Evolution.Experiment.Density`); the result
  reports the potential graph's mean degree (`potential_degree`) and the mean number of
  live neighbours per node over the run's iterations (`mean_degree`).

  ## What is measured

    * **solved**: a node holds a controller that solves OR (`OrGate.solved?/1`);
    * **first solution** `t1`: the first iteration at whose end some node is solved;
    * **convergence** `t90`: the first iteration at whose end at least `converge` (0.9) of
      the nodes are solved, by their own evolution or by sharing;
    * **Omega** (convergence count) = `t90 - t1`, the thesis's "iterations from the first
      best solution found by a node till 90% of the population converges";
    * **gamma_avg**: communications per node, sending and receiving, from the platform's
      own counters (`TartarusEmu.Log`): broadcast messages sent and received, plus, for
      iPkts, departures and arrivals (one hand-off is one message each way in this count,
      as the thesis counts a packet's migration), up to convergence.

  A run that does not converge within `max_iterations` reports `converged: false` and
  `omega: nil`.
  """

  alias Tartarus.Clock
  alias TartarusEmu.{Dynamics, Log, Network, Topology}
  alias TartarusImmune.Evolution.{Courier, IPkt, Learner}

  require Tartarus.Clock

  @schema [
    nodes: [type: :pos_integer, default: 20, doc: "robot nodes"],
    scheme: [
      type: {:in, [:broadcast, :ipkt, :none]},
      default: :broadcast,
      doc: "how controllers are shared"
    ],
    ipkts: [type: :pos_integer, default: 1, doc: "iPkts (scheme `:ipkt`)"],
    degree: [
      type: :pos_integer,
      default: 5,
      doc: "link stubs per node: potential neighbours at most (5, the thesis's)"
    ],
    p: [
      type: :probability,
      default: 0.1,
      doc: "per-iteration probability that a link breaks (or heals)"
    ],
    max_iterations: [type: :pos_integer, default: 3000, doc: "give up after this many iterations"],
    converge: [
      type: :probability,
      default: 0.9,
      doc: "fraction of solved nodes that counts as converged"
    ],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    seed: [type: :integer, default: 1, doc: "seed (network, dynamics, learners, iPkts)"]
  ]

  @doc "The options of `run/1`."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  The potential-neighbour graph: nodes `"n1".."nN"`, each with at most `degree` (5)
  neighbours (`degree` stubs per node, shuffled with `seed` and paired; self-pairs and
  repeats dropped).

      iex> t = TartarusImmune.Evolution.Sharing.topology(40, 1)
      iex> Enum.all?(t.nodes, &(length(TartarusEmu.Topology.neighbours(t, &1)) <= 5))
      true
      iex> t == TartarusImmune.Evolution.Sharing.topology(40, 1, 5)
      true
      iex> t = TartarusImmune.Evolution.Sharing.topology(40, 1, 12)
      iex> Enum.all?(t.nodes, &(length(TartarusEmu.Topology.neighbours(t, &1)) <= 12))
      true
  """
  @spec topology(pos_integer(), integer(), pos_integer()) :: Topology.t()
  def topology(n, seed, degree \\ 5) do
    names = for i <- 1..n, do: "n#{i}"
    rng = :rand.seed_s(:exsss, {seed, 7, 5})
    stubs = for name <- names, _ <- 1..degree, do: name

    {shuffled, _} =
      stubs
      |> Enum.map_reduce(rng, fn s, rng ->
        {u, rng} = :rand.uniform_s(rng)
        {{u, s}, rng}
      end)

    edges =
      shuffled
      |> Enum.sort()
      |> Enum.map(&elem(&1, 1))
      |> Enum.chunk_every(2, 2, :discard)
      |> Enum.flat_map(fn [a, b] -> if a == b, do: [], else: [{min(a, b), max(a, b)}] end)
      |> Enum.uniq()

    Topology.new(names, edges)
  end

  @doc """
  Runs the experiment once. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, result}` with `nodes, scheme, ipkts, degree, potential_degree,
  mean_degree, iterations, first_solved_at, converged_at, converged, omega, gamma_avg,
  communications` (a map of the counters summed) and `solved` (`[{iteration, solved_nodes}]`), or `{:error, message}`.
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "#{inspect(__MODULE__)}.run/1") do
      {:ok, do_run(Map.new(opts))}
    end
  end

  defp do_run(o) do
    topo = topology(o.nodes, o.seed, o.degree)
    {:ok, net} = Network.start(topo, mode: o.mode)

    try do
      {:ok, log} = Log.start(net)

      learners =
        for {name, i} <- Enum.with_index(topo.nodes) do
          {:ok, id} =
            Tartarus.create_static_agent(Network.host(net, name), Learner, %{
              seed: :erlang.phash2({o.seed, :learner, i})
            })

          id
        end

      ipkts =
        if o.scheme == :ipkt do
          for k <- 0..(o.ipkts - 1) do
            name = Enum.at(topo.nodes, div(k * o.nodes, o.ipkts))

            {:ok, id} =
              Tartarus.create_agent(Network.host(net, name), IPkt, %{driver: self()},
                seed: {o.seed, :ipkt, k}
              )

            id
          end
        else
          []
        end

      dyn = Dynamics.new(MapSet.to_list(topo.edges))
      rng = Dynamics.rng(o.seed)

      state = %{
        net: net,
        learners: learners,
        ipkts: ipkts,
        dyn: dyn,
        rng: rng,
        shared: 0,
        edges: MapSet.size(topo.edges),
        live: 0
      }

      result = loop(o, state, 1, nil, [])
      totals = Log.settled_totals(log)
      Log.stop(log)

      comm =
        Map.new([:broadcast_messages, :broadcasts_received, :departures, :arrivals], fn k ->
          {k, Map.get(totals, k, 0)}
        end)

      Map.merge(result, %{
        nodes: o.nodes,
        scheme: o.scheme,
        ipkts: if(o.scheme == :ipkt, do: o.ipkts, else: 0),
        degree: o.degree,
        potential_degree: Float.round(2 * MapSet.size(topo.edges) / o.nodes, 2),
        communications: comm,
        gamma_avg: Float.round(Enum.sum(Map.values(comm)) / o.nodes, 2)
      })
    after
      Network.stop(net)
    end
  end

  defp loop(o, s, t, first, solved_series) do
    {events, dyn, rng} = Dynamics.step(s.dyn, o.p, s.rng)

    Enum.each(events, fn
      {:down, {a, b}} -> Network.break_link(s.net, a, b)
      {:up, {a, b}} -> Network.heal_link(s.net, a, b)
    end)

    # live links this iteration, for the mean degree over the run
    live = s.live + s.edges - length(Dynamics.down(dyn))
    s = %{s | dyn: dyn, rng: rng, live: live}
    _ = ask_all(s.learners, :iterate)
    s = share(o.scheme, s)
    solved = s.learners |> ask_all(:status) |> Enum.count(& &1.solved)
    series = [{t, solved} | solved_series]
    first = first || if(solved > 0, do: t)

    cond do
      solved >= o.converge * o.nodes ->
        Map.put(finish(first, t, series, t), :mean_degree, mean_degree(s, o, t))

      t >= o.max_iterations ->
        Map.put(finish(first, nil, series, t), :mean_degree, mean_degree(s, o, t))

      true ->
        loop(o, s, t + 1, first, series)
    end
  end

  defp mean_degree(s, o, t), do: Float.round(2 * s.live / (o.nodes * t), 2)

  defp finish(first, t90, series, t) do
    %{
      iterations: t,
      first_solved_at: first,
      converged_at: t90,
      converged: t90 != nil,
      omega: if(t90 && first, do: t90 - first),
      solved: Enum.reverse(series)
    }
  end

  defp share(:none, s), do: s

  defp share(:broadcast, s) do
    sent = s.learners |> ask_all(:share) |> Enum.sum()
    expected = s.shared + sent
    await_received(s.learners, expected, 30_000)
    _ = ask_all(s.learners, :absorb)
    %{s | shared: expected}
  end

  defp share(:ipkt, s) do
    Enum.each(s.ipkts, fn id -> {:ok, :ok} = Tartarus.request(id, :visit, 10_000) end)

    Enum.each(s.ipkts, fn id ->
      Clock.receive do
        {tag, ^id} when tag in [:ipkt_moved, :ipkt_stayed] -> :ok
      after
        10_000 -> raise "iPkt #{id} neither moved nor stayed within 10 s"
      end
    end)

    s
  end

  # Broadcasts are delivered by each node's overlay process, after :share has answered:
  # wait until every one sent so far has been received, so that :absorb sees them all and
  # a run does not depend on the scheduler. No host stops here, so a broadcast that never
  # arrives is an error, not something to absorb without.
  defp await_received(learners, expected, tries) do
    count = fn -> learners |> ask_all(:status) |> Enum.map(& &1.received) |> Enum.sum() end
    Courier.await_count(count, expected, tries, "broadcasts")
  end

  defp ask_all(ids, msg) do
    ids
    |> Task.async_stream(
      fn id ->
        {:ok, r} = Tartarus.request(id, msg, 30_000)
        r
      end,
      max_concurrency: System.schedulers_online() * 2,
      timeout: 60_000
    )
    |> Enum.map(fn {:ok, r} -> r end)
  end
end
