defmodule TartarusTools.Chaos do
  @moduledoc """
  The fault-injection harness behind `mix tartarus.chaos`: real BEAM nodes, agents migrating
  at random, nodes killed with SIGKILL and restarted, pairs of nodes partitioned and healed;
  at the end everything is healed and the agents are counted.

  ## The workload

  The agents (`TartarusTools.Chaos.Counter`) have a state that changes: each records every
  message it takes (`{:msg, seq}`, numbered per agent by the harness). Each step of the
  eight workers is one migration attempt - mostly a `Tartarus.move/2` ordered from outside,
  sometimes a move the agent makes itself (it is posted `{:go, dest}` and returns
  `{:move, dest, state}`), sometimes a `Tartarus.clone/2` (the clone is tracked like the
  other agents) - followed by one `Tartarus.post/3` of a numbered message to a random
  agent. A post that returned `:ok` is *acknowledged*: the harness remembers it.

  While the workers run, a **census** every `:census_ms` (default 1,000) lists every
  host's resident agents and asks each copy to answer (`Tartarus.agent_info/1` through
  that host); an id resident and alive on two hosts at once, and still so a moment later,
  is a *transient duplicate*.

  ## What it measures

    * `duplicates` - extra copies: an agent id found on more than one host (must be 0);
    * `lost` - agents created and never found again;
    * `lost_on_dead_hosts` - of those, agents that were (as far as the driver knows) on a
      node when it was killed. Without persistence, killing a node loses its agents, so a
      correct platform has `lost == lost_on_dead_hosts`; with persistence (`persist: true`,
      every host checkpoints to its own data directory and is restarted on it) `lost` must
      be 0;
    * `transient_duplicates` - copies seen running at once by the census (must be 0);
      `census_rounds`, `census_unanswered` (a listed resident that did not answer: it may
      have been leaving);
    * `acknowledged` - posts that returned `:ok`; `acknowledged_missing` - of those, messages
      not in the agent's state at the end (agents found at the end only);
      `acknowledged_missing_after_kill` - of those, messages of agents that were restored
      from their arrival snapshot (their node was SIGKILLed and restarted, or they crashed;
      each agent reports its arrivals, and the same hop count twice is a restore): without a
      durability mode, persistence restores an agent as it was at its last arrival, so those
      can be lost and are reported apart, not as a failure of the default mode; `acknowledged_of_lost_agents` - acknowledged messages of agents
      not found at the end;
    * `clones`, `agent_moves` (moves the agents asked for themselves), `posts`,
      `post_failures` (reason => count), `clone_failures` (kind of error => count: a
      `:timeout` or `:destination_down` clone may have committed), `untracked_agents`
      (agents found at the end that the harness did not create: a clone whose outcome it
      never learnt).

  A **rogue node** replays captured hand-offs: every host hands a copy of each `prepare` it
  receives, as sent (sealed, whole), to the harness (`Tartarus.Fault` point
  `:prepare_received`), which keeps the last 1,000; `:replays` times, spread over the run,
  one of them, drawn at random (most are for agents that have moved on since), is sent
  again to the host that received it, from an extra node that runs no host. A replay that
  were admitted would show as a duplicate, a transient duplicate or an untracked agent;
  `replays` counts those sent.

  The schedule of moves, kills and partitions is drawn from `seed`; the interleaving with
  the nodes' own timing is not deterministic (that is the point of a chaos run).

  ## How faults are made

    * a kill is `kill -9` of the node's OS process (`TartarusTools.Peer.kill/1`); the node is
      restarted under the same name a moment later (on the same data directory with
      persistence, empty without);
    * a partition gives two nodes wrong cookies for each other and closes their connection,
      so neither can reconnect until it is healed (`TartarusTools.Peer.partition/2`);
    * a server kill (`:server_kills`, default 0) is an untrappable `Process.exit(pid, :kill)`
      of a node's host server: the node and its agents stay up, the host's supervisor
      starts a new server that adopts them (`Tartarus.Host.Warden`). Its agents are not
      marked as on a killed node: one lost to it counts as lost.
  """

  alias TartarusTools.Peer
  alias TartarusTools.Chaos.Counter
  alias Tartarus.Clock
  require Tartarus.Clock

  @workers 8

  @doc """
  Runs a chaos experiment. Options: `:nodes` (default 8), `:agents` (500), `:migrations`
  (10_000), `:kills` (20), `:partitions` (20), `:persist` (false), `:seed` (1),
  `:progress` (a 1-arity fun called with the number of migrations attempted so far),
  `:census_ms` (1_000; 0 turns the census off), `:replays` (200; captured prepares sent
  again from a rogue node, 0 for none), `:host_opts` (extra options for every host, e.g.
  `[durable: true]` on a platform that has them).
  Returns a map of results (see the moduledoc).
  """
  @spec run(keyword()) :: map()
  def run(opts) do
    n = Keyword.get(opts, :nodes, 8)
    agents = Keyword.get(opts, :agents, 500)
    migrations = Keyword.get(opts, :migrations, 10_000)
    kills = Keyword.get(opts, :kills, 20)
    partitions = Keyword.get(opts, :partitions, 20)
    server_kills = Keyword.get(opts, :server_kills, 0)
    persist = Keyword.get(opts, :persist, false)
    seed = Keyword.get(opts, :seed, 1)
    progress = Keyword.get(opts, :progress, fn _ -> :ok end)
    if n < 2, do: raise(ArgumentError, "a chaos run needs at least 2 nodes, got: #{n}")

    # Unique on this machine: several harnesses (a test, a run) may start nodes at once.
    tag = "#{System.unique_integer([:positive])}_#{:os.getpid()}"
    dir = Path.join(System.tmp_dir!(), "tartarus_chaos_#{tag}")
    names = for i <- 1..n, do: :"chaos#{i}_#{tag}"
    rogue_name = :"chaos_rogue_#{tag}"
    replays = Keyword.get(opts, :replays, 200)

    world = %{
      names: names,
      dir: dir,
      persist: persist,
      migrations: migrations,
      host_opts: Keyword.get(opts, :host_opts, []),
      table: :ets.new(:chaos, [:public, :set, write_concurrency: true]),
      acked: :ets.new(:chaos_acked, [:public, :bag, write_concurrency: true]),
      captured: if(replays > 0, do: spawn_link(fn -> capture_loop(:queue.new(), 0) end))
    }

    world = Map.put(world, :arrivals, spawn_link(fn -> arrivals_loop(world.table) end))

    t0 = Clock.machine_time(:millisecond)

    try do
      nodes = Enum.map(names, &start_node(world, &1))
      hosts = Enum.map(nodes, &{:h, &1})

      ids =
        for i <- 1..agents do
          host = Enum.at(hosts, rem(i, n))
          {:ok, id} = Tartarus.create_mobile_agent(host, Counter, {i, world.arrivals})
          :ets.insert(world.table, {{:loc, id}, host})
          id
        end

      rng = :rand.seed_s(:exsss, {seed, 7, 11})
      # Marks in successful migrations, spread over the first two thirds of the run.
      faults = schedule(div(migrations * 2, 3), kills, partitions, server_kills, rng)
      # 1: migrations attempted, 2: migrations done, 3: 1 while a killed node restarts
      counter = :atomics.new(3, [])

      workers =
        for w <- 1..@workers do
          Task.async(fn -> worker(world, ids, hosts, migrations, counter, {seed, w}) end)
        end

      census = Task.async(fn -> census(world, hosts, Keyword.get(opts, :census_ms, 1_000)) end)
      rogue = Task.async(fn -> rogue(world, rogue_name, replays, counter, seed) end)
      run_faults(world, faults, counter, nodes, progress, {seed, 0})
      Task.await_many(workers, :infinity)
      send(census.pid, :stop)
      send(rogue.pid, :stop)
      census_result = Task.await(census, :infinity)
      replays_sent = Task.await(rogue, :infinity)

      heal_all(world, nodes)
      settle(hosts)
      world
      |> count(ids, hosts, counter, kills, partitions, persist, seed, n, t0)
      |> Map.merge(census_result)
      |> Map.put(:replays, replays_sent)
      |> Map.put(:server_kills, server_kills)
    after
      for pid <- [world.captured, world.arrivals], is_pid(pid) do
        Process.unlink(pid)
        Process.exit(pid, :kill)
      end

      for name <- [rogue_name | names], do: Peer.kill(node_of(name))
      File.rm_rf(dir)
    end
  end

  # Migrations are spread over the run; each fault fires when the number of migrations
  # attempted so far reaches its mark.
  defp schedule(migrations, kills, partitions, server_kills, rng) do
    {marks, _} =
      Enum.map_reduce(
        List.duplicate(:kill, kills) ++
          List.duplicate(:partition, partitions) ++ List.duplicate(:server_kill, server_kills),
        rng,
        fn kind, rng ->
          {x, rng} = :rand.uniform_s(max(migrations, 1), rng)
          {{x, kind}, rng}
        end
      )

    Enum.sort(marks)
  end

  defp worker(world, ids, hosts, migrations, counter, {seed, w}) do
    rng = :rand.seed_s(:exsss, {seed, w, 5})
    ids = List.to_tuple(ids)
    hosts = List.to_tuple(hosts)
    loop(world, ids, hosts, migrations, counter, rng)
  end

  defp loop(world, ids, hosts, migrations, counter, rng) do
    # Workers hold off while a killed node restarts: failed attempts are quick, and without
    # this the schedule's later faults would all fall due at once, with nobody moving.
    if :atomics.get(counter, 3) == 1, do: Clock.sleep(20)

    {i, rng} = :rand.uniform_s(tuple_size(ids), rng)
    {j, rng} = :rand.uniform_s(tuple_size(hosts), rng)
    id = elem(ids, i - 1)
    dest = elem(hosts, j - 1)

    cond do
      # Agents known to have gone down with a node are not picked (without persistence they
      # are gone; with it they are picked again once their node restored them).
      :ets.member(world.table, {:on_dead, id}) and not all_dead?(world, ids) ->
        loop(world, ids, hosts, migrations, counter, rng)

      :atomics.add_get(counter, 1, 1) > migrations ->
        :ok

      true ->
        {op, rng} = :rand.uniform_s(100, rng)
        {k, rng} = :rand.uniform_s(tuple_size(ids), rng)

        cond do
          op <= 80 -> move_one(world, id, dest, counter)
          op <= 95 -> agent_move(world, id, dest)
          true -> clone_one(world, id, dest)
        end

        post_one(world, elem(ids, k - 1))
        loop(world, ids, hosts, migrations, counter, rng)
    end
  end

  # The agent moves itself: it is posted `{:go, dest}`; whether the move succeeds is not
  # known here (its old host keeps a forwarding pointer if it does).
  defp agent_move(world, id, dest) do
    [{_, here}] = :ets.lookup(world.table, {:loc, id})

    case safe_post({id, here}, {:go, dest}) do
      :ok -> :ets.update_counter(world.table, :agent_moves, 1, {:agent_moves, 0})
      _ -> :ok
    end
  end

  defp clone_one(world, id, dest) do
    [{_, here}] = :ets.lookup(world.table, {:loc, id})

    case safe_call(fn -> Tartarus.clone({id, here}, dest) end) do
      {:ok, clone} ->
        :ets.insert(world.table, {{:clone, clone}, dest})
        :ets.insert(world.table, {{:loc, clone}, dest})

        if :ets.member(world.table, {:dead, elem(dest, 1)}),
          do: :ets.insert(world.table, {{:on_dead, clone}, true})

      {:error, reason} ->
        key = {:clone_failed, failure_kind(reason)}
        :ets.update_counter(world.table, key, 1, {key, 0})
    end
  end

  # A clone failure by kind (its reason without the node names and pids in it).
  defp failure_kind(reason) when is_tuple(reason), do: inspect(elem(reason, 0))
  defp failure_kind(reason), do: inspect(reason)

  # One numbered message to an agent; an `:ok` is remembered as acknowledged.
  defp post_one(world, id) do
    if :ets.member(world.table, {:on_dead, id}) do
      :ok
    else
      [{_, here}] = :ets.lookup(world.table, {:loc, id})
      seq = :ets.update_counter(world.table, {:seq, id}, 1, {{:seq, id}, 0})

      case safe_post({id, here}, {:msg, seq}) do
        :ok ->
          :ets.insert(world.acked, {id, seq})

        {:error, reason} ->
          key = {:post_failed, inspect(reason)}
          :ets.update_counter(world.table, key, 1, {key, 0})
      end
    end
  end

  defp safe_post(ref, msg), do: safe_call(fn -> Tartarus.post(ref, msg) end)

  defp safe_call(fun) do
    fun.()
  catch
    _, reason -> {:error, reason}
  end

  defp all_dead?(world, ids),
    do: :ets.select_count(world.table, [{{{:on_dead, :_}, :_}, [], [true]}]) >= tuple_size(ids)

  defp move_one(world, id, dest, counter) do
    [{_, here}] = :ets.lookup(world.table, {:loc, id})

    case safe_move({id, here}, dest) do
      :ok ->
        :atomics.add(counter, 2, 1)
        locate(world, id, dest)

      {:error, {:destination_down, _}} ->
        # Committed to a node that died before the agent started there: lost with it.
        :ets.insert(world.table, {{:loc, id}, dest})
        :ets.insert(world.table, {{:on_dead, id}, true})

      _failed ->
        :ok
    end
  end

  defp safe_move(ref, dest) do
    Tartarus.move(ref, dest)
  catch
    _, reason -> {:error, reason}
  end

  # Records where an agent is now; an agent recorded on a dead node is lost with it.
  defp locate(world, id, {_, node} = host) do
    :ets.insert(world.table, {{:loc, id}, host})

    if :ets.member(world.table, {:dead, node}) do
      :ets.insert(world.table, {{:on_dead, id}, true})
    end
  end

  defp run_faults(_world, [], _counter, _nodes, progress, _seed), do: progress.(:done)

  defp run_faults(world, [{mark, kind} | rest], counter, nodes, progress, {seed, k}) do
    wait_for(counter, mark, world.migrations, progress)
    rng = :rand.seed_s(:exsss, {seed, k, 3})
    {a, rng} = :rand.uniform_s(length(nodes), rng)
    {b, _} = :rand.uniform_s(length(nodes) - 1, rng)
    node_a = Enum.at(nodes, a - 1)
    node_b = Enum.at(nodes -- [node_a], b - 1)

    case kind do
      :kill -> kill_and_restart(world, node_a, counter)
      :partition -> partition_for_a_while(node_a, node_b)
      :server_kill -> kill_server(node_a)
    end

    run_faults(world, rest, counter, nodes, progress, {seed, k + 1})
  end

  # A fault falls due when that many migrations have *succeeded* (failed attempts are quick,
  # so counting attempts would bunch the faults up once agents start to be lost), or when the
  # workers are done.
  defp wait_for(counter, mark, migrations, progress) do
    attempted = :atomics.get(counter, 1)
    progress.(attempted)

    if :atomics.get(counter, 2) < mark and attempted <= migrations do
      Clock.sleep(10)
      wait_for(counter, mark, migrations, progress)
    end
  end

  defp kill_and_restart(world, node, counter) do
    # The agents resident on the node (asked just before the kill, so an agent lost earlier
    # elsewhere is not excused by this kill) go down with it, unless persistence brings them
    # back; so do agents that arrive while the node is marked dead.
    :ets.insert(world.table, {{:dead, node}, true})

    for %{id: id} <- List.wrap(Tartarus.agents({:h, node})) do
      :ets.insert(world.table, {{:on_dead, id}, true})
    end

    Peer.kill(node)
    :atomics.put(counter, 3, 1)
    Clock.sleep(100)
    name = node |> Atom.to_string() |> String.split("@") |> hd() |> String.to_atom()
    ^node = start_node(world, name)
    :ets.delete(world.table, {:dead, node})

    # With persistence the node restored its agents: they are alive again.
    for %{id: id} <- List.wrap(Tartarus.agents({:h, node})),
        do: :ets.delete(world.table, {:on_dead, id})

    # Nobody keeps a partition against the new incarnation.
    for other <- nodes_of(world), other != node, do: Peer.heal(node, other)
    :atomics.put(counter, 3, 0)
  end

  # The host's server on `node`, killed (untrappable); its supervisor starts another.
  defp kill_server(node) do
    case :erpc.call(node, Tartarus.Host, :whereis, [{:h, node}], 5_000) do
      {:ok, pid} -> :erpc.call(node, Process, :exit, [pid, :kill], 5_000)
      _ -> :ok
    end
  catch
    # The node may be down (restarting): nothing to kill.
    _, _ -> :ok
  end

  defp partition_for_a_while(a, b) do
    try do
      Peer.partition(a, b)
    catch
      # One of them may be down (restarting): nothing to cut.
      _, _ -> :ok
    end

    Clock.sleep(300)
    Peer.heal(a, b)
  end

  defp start_node(world, name) do
    {:ok, _pid, node} = Peer.start(name, link: false)

    host_opts =
      [migration_timeout: 1_000] ++
        if(world.persist, do: [data_dir: Path.join(world.dir, "#{name}")], else: []) ++
        world.host_opts

    {:ok, _} = :erpc.call(node, Tartarus, :start_host, [:h, host_opts])

    if world.captured do
      hook = {:transform, {__MODULE__, :capture, [world.captured]}}
      :ok = :erpc.call(node, Tartarus.Fault, :install, [:prepare_received, hook])
    end

    node
  end

  # -- arrivals: which agents were restored ------------------------------------------

  # An agent's arrivals are counted by hop count: the same hop count twice means the agent
  # was started again from its arrival snapshot (a node restart restored it, or it crashed).
  defp arrivals_loop(table) do
    receive do
      {:chaos_arrival, id, hops, restarts} ->
        n = :ets.update_counter(table, {:arrival, id, hops}, 1, {{:arrival, id, hops}, 0})
        if n > 1 or restarts > 0, do: :ets.insert(table, {{:restored, id}, true})
        arrivals_loop(table)

      {:sync, from} ->
        send(from, :synced)
        arrivals_loop(table)
    end
  end

  # Waits until the arrival reports that reached this node so far are counted.
  defp sync_arrivals(world) do
    send(world.arrivals, {:sync, self()})

    receive do
      :synced -> :ok
    end
  end

  # -- the rogue node ----------------------------------------------------------------

  @doc false
  # The `:prepare_received` hook on every node: a copy of the message, and the host that
  # received it (its server, which takes a replay: the process that admitted the original
  # is gone or the copy), goes to the harness; the message itself goes on unchanged.
  def capture(msg, collector) do
    server =
      case Tartarus.Host.whereis({:h, node()}) do
        {:ok, pid} -> pid
        _ -> self()
      end

    send(collector, {:captured, server, msg})
    msg
  end

  @keep 1_000

  defp capture_loop(queue, size) do
    receive do
      {:captured, pid, msg} when size < @keep ->
        capture_loop(:queue.in({pid, msg}, queue), size + 1)

      {:captured, pid, msg} ->
        capture_loop(:queue.in({pid, msg}, :queue.drop(queue)), size)

      {:pick, from, i} ->
        send(from, {:picked, if(size == 0, do: nil, else: Enum.at(:queue.to_list(queue), rem(i, size)))})
        capture_loop(queue, size)
    end
  end

  # Sends `replays` captured prepares again, from a node of its own, spread over the run (one
  # each time another `migrations / replays` migrations were attempted). Returns how many it
  # sent.
  defp rogue(_world, _name, 0, _counter, _seed) do
    receive do
      :stop -> 0
    end
  end

  defp rogue(world, name, replays, counter, seed) do
    {:ok, _pid, node} = Peer.start(name, link: false)
    rng = :rand.seed_s(:exsss, {seed, 13, 17})
    rogue_loop(world, node, replays, counter, rng, 0)
  end

  defp rogue_loop(world, node, replays, counter, rng, sent) do
    Clock.receive do
      # The workers are done: what is still due goes now.
      :stop -> elem(replay(world, node, replays - sent, rng), 1) + sent
    after
      10 ->
        due = div(:atomics.get(counter, 1) * replays, max(world.migrations, 1))
        {rng, n} = replay(world, node, min(due, replays) - sent, rng)
        rogue_loop(world, node, replays, counter, rng, sent + n)
    end
  end

  # Sends up to `n` captured prepares again; returns how many (none while none is captured).
  defp replay(world, node, n, rng), do: replay(world, node, n, rng, 0)

  defp replay(_world, _node, n, rng, done) when n <= 0, do: {rng, done}

  defp replay(world, node, n, rng, done) do
    {i, rng} = :rand.uniform_s(@keep, rng)
    send(world.captured, {:pick, self(), i})

    receive do
      {:picked, nil} ->
        {rng, done}

      {:picked, {pid, msg}} ->
        :erpc.cast(node, :erlang, :send, [pid, msg])
        replay(world, node, n - 1, rng, done + 1)
    end
  end

  defp nodes_of(world), do: Enum.map(world.names, &node_of/1)

  defp node_of(name) do
    [_, host] = node() |> Atom.to_string() |> String.split("@")
    :"#{name}@#{host}"
  end

  defp heal_all(_world, nodes) do
    for a <- nodes, b <- nodes, a < b, do: Peer.heal(a, b)
    :ok
  end

  # Waits until no host holds a paused (in-doubt) copy, at most 60 s.
  defp settle(hosts, tries \\ 600) do
    paused = Enum.sum(for h <- hosts, do: paused(h))

    if paused > 0 and tries > 0 do
      Clock.sleep(100)
      settle(hosts, tries - 1)
    else
      paused
    end
  end

  defp paused(host) do
    case Tartarus.Host.call(host, :paused) do
      n when is_integer(n) -> n
      _ -> 0
    end
  end

  # -- census ----------------------------------------------------------------------

  # Every `every_ms` until told to stop: each host lists its residents, each copy is asked to
  # answer; an id resident and alive on two hosts, and still so 200 ms later, counts as a
  # transient duplicate (a hand-off's source leaves the resident list as it commits, so a
  # copy caught mid-move has left by then).
  defp census(_world, _hosts, 0) do
    receive do
      :stop -> %{census_rounds: 0, transient_duplicates: 0, census_unanswered: 0}
    end
  end

  defp census(world, hosts, every_ms), do: census(world, hosts, every_ms, {0, 0, 0})

  defp census(world, hosts, every_ms, {rounds, dups, unanswered}) do
    Clock.receive do
      :stop -> %{census_rounds: rounds, transient_duplicates: dups, census_unanswered: unanswered}
    after
      every_ms ->
        {d, u} = census_round(hosts)
        census(world, hosts, every_ms, {rounds + 1, dups + d, unanswered + u})
    end
  end

  defp census_round(hosts) do
    listed =
      hosts
      |> Task.async_stream(
        fn h ->
          residents = residents(h)

          unanswered =
            Enum.count(residents, fn %{id: id} ->
              not match?({:ok, _}, safe_call(fn -> Tartarus.agent_info({id, h}) end))
            end)

          {Enum.map(residents, &{&1.id, &1.pid}), unanswered}
        end,
        timeout: :infinity,
        ordered: false
      )
      |> Enum.map(fn {:ok, r} -> r end)

    unanswered = Enum.sum(Enum.map(listed, &elem(&1, 1)))

    suspects =
      listed
      |> Enum.flat_map(&elem(&1, 0))
      |> Enum.group_by(&elem(&1, 0), &elem(&1, 1))
      |> Enum.filter(fn {_, pids} -> length(Enum.uniq(pids)) > 1 end)
      |> Enum.filter(fn {_, pids} -> Enum.count(pids, &alive?/1) > 1 end)

    if suspects != [], do: Clock.sleep(200)

    dups =
      Enum.count(suspects, fn {id, pids} ->
        still = hosts |> Enum.flat_map(&resident_pids(&1, id)) |> Enum.filter(&(&1 in pids))
        Enum.count(still, &alive?/1) > 1
      end)

    {dups, unanswered}
  end

  defp resident_pids(host, id), do: for(%{id: ^id, pid: pid} <- residents(host), do: pid)

  # The residents of a host; none if it does not answer.
  defp residents(host) do
    case safe_call(fn -> Tartarus.agents(host) end) do
      list when is_list(list) -> list
      _ -> []
    end
  end

  defp alive?(pid) do
    :erpc.call(node(pid), :erlang, :is_process_alive, [pid], 2_000)
  catch
    _, _ -> false
  end

  # -- the end ---------------------------------------------------------------------

  defp count(world, ids, hosts, counter, kills, partitions, persist, seed, n, t0) do
    residents =
      Enum.flat_map(hosts, fn h -> Enum.map(residents(h), &{&1.id, h}) end)

    clones = for [id] <- :ets.match(world.table, {{:clone, :"$1"}, :_}), do: id
    tracked = ids ++ clones
    freq = Enum.frequencies(Enum.map(residents, &elem(&1, 0)))
    duplicates = freq |> Map.values() |> Enum.map(&(&1 - 1)) |> Enum.sum()
    lost = Enum.reject(tracked, &Map.has_key?(freq, &1))
    on_dead = Enum.count(lost, &:ets.member(world.table, {:on_dead, &1}))
    tracked_set = MapSet.new(tracked)
    where = Map.new(residents)
    :ok = sync_arrivals(world)
    acked = acknowledged(world, ids, where)

    post_failures =
      for {{:post_failed, reason}, n} <- :ets.tab2list(world.table), into: %{}, do: {reason, n}

    clone_failures =
      for {{:clone_failed, kind}, n} <- :ets.tab2list(world.table), into: %{}, do: {kind, n}

    %{
      nodes: n,
      agents_start: length(ids),
      agents_end: map_size(freq),
      clones: length(clones),
      clone_failures: clone_failures,
      untracked_agents: Enum.count(Map.keys(freq), &(not MapSet.member?(tracked_set, &1))),
      duplicates: duplicates,
      lost: length(lost),
      lost_on_dead_hosts: on_dead,
      migrations_done: :atomics.get(counter, 2),
      agent_moves: counter_of(world, :agent_moves),
      posts: acked.acknowledged + Enum.sum(Map.values(post_failures)),
      post_failures: post_failures,
      acknowledged: acked.acknowledged,
      acknowledged_missing: acked.missing,
      acknowledged_missing_after_kill: acked.missing_after_kill,
      acknowledged_of_lost_agents: acked.of_lost,
      kills: kills,
      partitions: partitions,
      persist: persist,
      host_opts: inspect(world.host_opts),
      seed: seed,
      still_in_doubt: settle(hosts, 0),
      wall_ms: Clock.machine_time(:millisecond) - t0
    }
  end

  defp counter_of(world, key) do
    case :ets.lookup(world.table, key) do
      [{_, n}] -> n
      [] -> 0
    end
  end

  # Every acknowledged message must be in its agent's state (for agents found at the end).
  defp acknowledged(world, ids, where) do
    Enum.reduce(ids, %{acknowledged: 0, missing: 0, missing_after_kill: 0, of_lost: 0}, fn id,
                                                                                          acc ->
      seqs = for {_, seq} <- :ets.lookup(world.acked, id), do: seq
      acc = %{acc | acknowledged: acc.acknowledged + length(seqs)}

      case Map.fetch(where, id) do
        :error ->
          %{acc | of_lost: acc.of_lost + length(seqs)}

        {:ok, host} ->
          got =
            case safe_call(fn -> Tartarus.agent_info({id, host}) end) do
              {:ok, %{state: %{got: got}}} -> got
              _ -> MapSet.new()
            end

          missing = Enum.count(seqs, &(not MapSet.member?(got, &1)))
          restored? = :ets.member(world.table, {:restored, id})

          %{
            acc
            | missing: acc.missing + missing,
              missing_after_kill: acc.missing_after_kill + if(restored?, do: missing, else: 0)
          }
      end
    end)
  end
end

defmodule TartarusTools.Chaos.Counter do
  @moduledoc """
  The agent of the chaos harness: its state records every message `{:msg, seq}` it takes
  (`got`, a set of seqs; `count`, how many it took, duplicates included), so a rollback or
  a second copy shows. `{:go, dest}` makes it move itself to `dest`. Its creation and each
  arrival (after a move, a clone, a crash or a restore from a checkpoint) are reported to `report` as
  `{:chaos_arrival, id, hops, restarts}`: an arrival reported twice with the same hop count
  is a restore, which is how the harness knows which agents went back to an arrival
  snapshot.
  """
  use Tartarus.Agent

  @impl true
  def init({i, report}) do
    send(report, {:chaos_arrival, Tartarus.Agent.id(), 0, 0})
    {:stay, %{i: i, report: report, got: MapSet.new(), count: 0}}
  end

  @impl true
  def handle_arrival(ctx, s) do
    send(s.report, {:chaos_arrival, Tartarus.Agent.id(), ctx.hops, ctx.restarts})
    {:stay, s}
  end

  @impl true
  def handle_message({:msg, seq}, _from, s),
    do: {:stay, %{s | got: MapSet.put(s.got, seq), count: s.count + 1}}

  def handle_message({:go, dest}, _from, s), do: {:move, dest, s}
  def handle_message(_other, _from, s), do: {:stay, s}
end
