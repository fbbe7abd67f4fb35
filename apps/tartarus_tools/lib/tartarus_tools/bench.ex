defmodule TartarusTools.Bench do
  @moduledoc """
  Benchmarks of the platform's real paths, run by `mix tartarus.bench`.

    * `migration/1` - agents bouncing between two hosts: in `:virtual` mode both hosts are
      in this VM; in `:peer` mode each host is on its own BEAM node (two `:peer` nodes on
      this machine, over distributed Erlang on loopback, optionally TLS). The agent module is
      compiled at run time on this node, so its code really ships (once per link).
    * `agents/1` - creating many idle agents on one host (in a peer node started with a
      process limit large enough), measuring the spawn rate and memory per agent.

  Results are maps (the JSON keys are documented in the README). Figures are medians of
  per-hop times from the hosts' ledgers (the most recent 1,024 arrivals per host) and
  throughput from wall-clock time of the whole run.
  """

  require Tartarus.Clock

  @bouncer """
  defmodule TartarusTools.Bench.Bouncer do
    @moduledoc false
    use Tartarus.Agent

    def init(state), do: {:stay, state}

    def handle_message(:go, _from, s), do: {:move, s.b, s}

    def handle_arrival(ctx, s) do
      left = s.left - 1
      s = Map.delete(s, :fails)
      if left <= 0, do: {:return, :done, %{s | left: 0}}, else: {:move, ctx.from, %{s | left: left}}
    end

    # A move that failed (a hand-off timed out on a loaded machine) is tried again, up to 10
    # times in a row; then the agent gives up and says why (the run raises with it).
    def handle_move_failed(dest, reason, _ctx, s) do
      fails = Map.get(s, :fails, 0) + 1
      if fails >= 10, do: {:return, {:failed, reason}, s}, else: {:move, dest, Map.put(s, :fails, fails)}
    end
  end
  """

  @doc """
  Runs the migration benchmark: two phases on the platform and the same two on the floor
  (`TartarusTools.Bench.Floor`: three distribution messages and a spawn of a paused
  process carrying the same state, no platform), in one run between the same two hosts'
  nodes.

    * latency: one agent makes `:latency_hops` hops (default 2,000); `us_per_hop` is wall
      time / hops (and `median_us`, `p99_us` come from the hosts' ledgers);
    * throughput: `:agents` agents (default 1,000) make `:hops` hops each (default 100)
      at once; `hops_per_s` is all hops / wall time.

  `ratio_latency` is `us_per_hop / floor_us_per_hop` and `ratio_throughput` is
  `hops_per_s / floor_hops_per_s`.

  Each phase runs in `:rounds` rounds (default 4: the hops are split among them, e.g. 4 x
  500 hops of one agent, 4 x 25 hops of 1,000 agents), each round running the floor and
  the platform one after the other, alternating which goes first, so that a change in the
  machine's load weighs on both alike; the wall times are summed.

  Options: `:mode` (`:virtual`: both hosts in this VM | `:peer`: each on its own BEAM
  node), `:latency_hops`, `:agents`, `:hops`, `:rounds`, `:state_bytes` (default 1024), `:tls`
  (peer mode over TLS distribution with mutual certificate authentication; certificates
  are made in a temporary directory), `:profile` (`:eprof`: profile the platform's
  throughput phase on the receiving node - the second peer - and return its costliest
  functions under `profile`; the timings of a profiled run are not comparable).

  In peer mode the benchmark is driven from the first peer (which hosts the agents'
  home), so the origin needs no distribution to the peers and TLS covers all the traffic
  that is measured.
  """
  @spec migration(keyword()) :: map()
  def migration(opts) do
    mode = Keyword.get(opts, :mode, :virtual)
    tls = Keyword.get(opts, :tls, false)
    if tls and mode != :peer, do: raise(ArgumentError, "--tls needs --mode peer")

    result =
      case mode do
        :virtual ->
          tag = System.unique_integer([:positive])
          {:ok, h2} = Tartarus.start_host(:"bench_b#{tag}")

          try do
            drive(h2, opts)
          after
            Tartarus.stop_host(h2)
          end

        :peer ->
          with_peers(tls, fn {pa, _a}, {pb, _b} ->
            {:ok, h2} = :peer.call(pb, Tartarus, :start_host, [:bench_b], 30_000)
            :peer.call(pa, __MODULE__, :drive, [h2, opts], :infinity)
          end)
      end

    Map.merge(result, %{mode: mode, tls: tls})
  end

  @doc false
  # Two fresh peer nodes (over TLS distribution if `tls`), controlled over standard I/O;
  # calls `fun.({pid_a, node_a}, {pid_b, node_b})` and stops them.
  def with_peers(tls, fun) do
    # Unique on this machine: other benchmarks may start peers at the same time.
    tag = "#{System.unique_integer([:positive])}_#{:os.getpid()}"
    dir = Path.join(System.tmp_dir!(), "tartarus_bench_#{tag}")
    names = [:"bench_a#{tag}", :"bench_b#{tag}"]

    args =
      if tls do
        {:ok, _} =
          Tartarus.Security.Certs.generate(dir, nodes: Enum.map(names, &Atom.to_string/1), days: 1)

        fn name -> Tartarus.Security.TLSDist.erl_flags(Atom.to_string(name), dir) end
      else
        fn _ -> [] end
      end

    peers =
      for name <- names do
        {:ok, pid, node} =
          TartarusTools.Peer.start(name,
            args: ["-setcookie", "tartarus_bench" | args.(name)],
            connection: :standard_io
          )

        {pid, node}
      end

    try do
      apply(fun, peers)
    after
      stop_peers(peers)
      File.rm_rf(dir)
    end
  end

  defp stop_peers(peers), do: Enum.each(peers, fn {pid, _} -> TartarusTools.Peer.stop(pid) end)

  @doc false
  # Runs on the node that hosts the agents' home; `h2` is the other end (here or remote).
  def drive(h2, opts) do
    latency_hops = Keyword.get(opts, :latency_hops, 2_000)
    hops = Keyword.get(opts, :hops, 100)
    agents = Keyword.get(opts, :agents, 1_000)
    state_bytes = Keyword.get(opts, :state_bytes, 1024)
    profile = Keyword.get(opts, :profile)
    rounds = if profile, do: 1, else: Keyword.get(opts, :rounds, 4)
    module = compile_bouncer()
    {:ok, h1} = Tartarus.start_host(:"bench_a#{System.unique_integer([:positive])}")
    other = elem(h2, 1)

    try do
      :ok = Tartarus.connect(h1, h2)
      blob = :crypto.strong_rand_bytes(state_bytes)
      floor_state = %{left: 0, b: h2, blob: blob}
      nodes = Enum.uniq([node(), other])

      # Warm-up: one agent crosses both ways, so the code is cached at both ends; the floor
      # too (its receivers start, the connection is up).
      run_agents(module, h1, h2, 1, 2, blob)
      TartarusTools.Bench.Floor.run(other, 1, 2, floor_state)

      code_bytes =
        Enum.sum(for n <- nodes, do: :erpc.call(n, Tartarus.Events, :totals, []).code_bytes)

      for h <- [h1, h2], do: :erpc.call(elem(h, 1), __MODULE__, :reset_local_ring, [h])

      # Latency: one agent at a time, in rounds alternating floor and platform (and which
      # goes first), so a change of the machine's load weighs on both alike.
      {floor_lat_us, lat_us} =
        alternate(split(latency_hops, rounds), fn h ->
          {fn -> TartarusTools.Bench.Floor.run(other, 1, h, floor_state) end,
           fn -> run_agents(module, h1, h2, 1, h, blob) end}
        end)

      times =
        [h1, h2]
        |> Enum.flat_map(&Tartarus.hop_times/1)
        |> Enum.sort()

      # Throughput: `agents` at once, `hops` each, in rounds likewise (a profile is taken in
      # one round, platform only).
      {floor_tp_us, tp_us} =
        if profile do
          floor_us = TartarusTools.Bench.Floor.run(other, agents, hops, floor_state)
          :ok = :erpc.call(other, TartarusTools.Bench.Profile, :start, [])
          {floor_us, run_agents(module, h1, h2, agents, hops, blob)}
        else
          alternate(split(hops, rounds), fn h ->
            {fn -> TartarusTools.Bench.Floor.run(other, agents, h, floor_state) end,
             fn -> run_agents(module, h1, h2, agents, h, blob) end}
          end)
        end

      profiled =
        if profile,
          do: %{profile: :erpc.call(other, TartarusTools.Bench.Profile, :stop, [30], 600_000)},
          else: %{}

      total_hops = agents * hops
      us_per_hop = lat_us / latency_hops
      floor_us_per_hop = floor_lat_us / latency_hops
      hops_per_s = total_hops * 1_000_000 / tp_us
      floor_hops_per_s = total_hops * 1_000_000 / floor_tp_us

      Map.merge(profiled, %{
        latency_hops: latency_hops,
        hops: hops,
        rounds: rounds,
        agents: agents,
        state_bytes: state_bytes,
        total_hops: total_hops,
        latency_wall_ms: div(lat_us, 1000),
        wall_ms: div(tp_us, 1000),
        us_per_hop: Float.round(us_per_hop, 1),
        floor_us_per_hop: Float.round(floor_us_per_hop, 1),
        ratio_latency: Float.round(us_per_hop / floor_us_per_hop, 3),
        median_us: TartarusTools.Stats.percentile(times, 0.5),
        p99_us: TartarusTools.Stats.percentile(times, 0.99),
        samples: length(times),
        hops_per_s: round(hops_per_s),
        floor_hops_per_s: round(floor_hops_per_s),
        ratio_throughput: Float.round(hops_per_s / floor_hops_per_s, 3),
        module_bytes_shipped: code_bytes,
        otp_release: List.to_string(:erlang.system_info(:otp_release)),
        schedulers: System.schedulers_online(),
        distribution: distribution()
      })
    after
      Tartarus.stop_host(h1)
    end
  end

  # The recent hop times of a host: `Tartarus.hop_times/1` where the facade has it, else the
  # older `local_hop_times` on the host's node.
  # `n` in `rounds` parts (the first ones one larger), none empty.
  defp split(n, rounds) do
    rounds = max(min(rounds, n), 1)
    for i <- 1..rounds, do: div(n, rounds) + if(i <= rem(n, rounds), do: 1, else: 0)
  end

  # Runs each part's floor and platform funs, alternating which goes first; returns the
  # summed wall times {floor_us, platform_us}.
  defp alternate(parts, funs) do
    parts
    |> Enum.with_index()
    |> Enum.reduce({0, 0}, fn {part, i}, {f, p} ->
      {floor, platform} = funs.(part)

      if rem(i, 2) == 0 do
        df = floor.()
        {f + df, p + platform.()}
      else
        dp = platform.()
        {f + floor.(), p + dp}
      end
    end)
  end

  defp distribution do
    case :init.get_argument(:proto_dist) do
      {:ok, [[proto]]} -> List.to_string(proto)
      _ -> "inet_tcp"
    end
  end

  @doc false
  # The bouncing agent's module, compiled at run time (so its code really ships).
  def bouncer, do: compile_bouncer()

  defp compile_bouncer do
    if Code.ensure_loaded?(TartarusTools.Bench.Bouncer) do
      TartarusTools.Bench.Bouncer
    else
      {:ok, [module]} = Tartarus.compile_string(@bouncer)
      module
    end
  end

  defp run_agents(module, h1, h2, n, hops, blob),
    do: run_batch(module, h1, h2, List.duplicate(hops, n), blob)

  @doc false
  # One agent per element of `plan` (its number of hops) bouncing between h1 and h2; returns
  # the wall time in µs from the first order to move to the last agent's end.
  def run_batch(module, h1, h2, plan, blob) do
    ids =
      for hops <- plan do
        state = %{left: hops, b: h2, blob: blob}
        {:ok, id} = Tartarus.create_mobile_agent(h1, module, state, owner: self())
        id
      end

    # Timed from the first order to move (creating the agents is not a migration).
    t0 = Tartarus.Clock.machine_time(:microsecond)
    Enum.each(ids, fn id -> :ok = Tartarus.post({id, h1}, :go) end)

    Enum.each(ids, fn id ->
      Tartarus.Clock.receive do
        {:tartarus_result, ^id, :done} -> :ok
        {:tartarus_result, ^id, {:failed, reason}} -> raise "agent #{id}: 10 moves in a row failed, the last #{inspect(reason)}"
      after
        300_000 -> raise "agent #{id} did not finish its hops within 5 minutes"
      end
    end)

    max(Tartarus.Clock.machine_time(:microsecond) - t0, 1)
  end

  @doc false
  def reset_local_ring(host) do
    {:ok, info} = Tartarus.Host.local(host)
    Tartarus.Ledger.reset_hops(info)
  end

  @doc """
  Runs the resident-agents benchmark on a fresh peer node: creates `:count` idle agents on
  one host with `:creators` concurrent creators and measures the creation rate and the
  node's memory growth per agent. With `profile: :eprof` the creation is profiled (every
  process of the peer) and the costliest functions are returned under `profile` (the rate
  of a profiled run is not comparable).
  """
  @spec agents(keyword()) :: map()
  def agents(opts) do
    count = Keyword.get(opts, :count, 100_000)
    creators = Keyword.get(opts, :creators, System.schedulers_online())
    profile = Keyword.get(opts, :profile)
    limit = max(count * 2 + 100_000, 262_144)

    {:ok, pid, _node} =
      TartarusTools.Peer.start(:"bench_agents_#{System.unique_integer([:positive])}_#{:os.getpid()}",
        args: ["+P", "#{limit}"],
        connection: :standard_io
      )

    try do
      :peer.call(pid, __MODULE__, :agents_local, [count, creators, profile], :infinity)
    after
      TartarusTools.Peer.stop(pid)
    end
  end

  @doc false
  def agents_local(count, creators, profile \\ nil) do
    {:ok, host} = Tartarus.start_host(:bench_residents, hibernate_after: 1_000)
    :erlang.garbage_collect()
    mem0 = :erlang.memory(:total)
    if profile, do: :ok = TartarusTools.Bench.Profile.start()
    t0 = Tartarus.Clock.machine_time(:microsecond)
    per = div(count, creators)

    1..creators
    |> Enum.map(fn i ->
      n = if i == creators, do: count - per * (creators - 1), else: per

      Task.async(fn ->
        for _ <- 1..n//1,
            do: {:ok, _} = Tartarus.create_mobile_agent(host, TartarusTools.Bench.Idle, nil)
      end)
    end)
    |> Task.await_many(:infinity)

    wall_us = max(Tartarus.Clock.machine_time(:microsecond) - t0, 1)
    profiled = if profile, do: %{profile: TartarusTools.Bench.Profile.stop(30)}, else: %{}
    # Resident and idle: let the agents hibernate (they do after 1 s without messages).
    Tartarus.Clock.machine_sleep(3_000)
    mem1 = :erlang.memory(:total)
    resident = Tartarus.status(host).resident

    Map.merge(profiled, %{
      agents: count,
      resident: resident,
      creators: creators,
      wall_ms: div(wall_us, 1000),
      spawn_per_s: round(count * 1_000_000 / wall_us),
      bytes_per_agent: div(mem1 - mem0, max(count, 1)),
      memory_mb: div(mem1, 1_048_576),
      process_limit: :erlang.system_info(:process_limit)
    })
  end
end

defmodule TartarusTools.Bench.Idle do
  @moduledoc false
  # An agent that does nothing: the unit of the resident-agents benchmark.
  use Tartarus.Agent
  def init(_), do: {:stay, nil}
end
