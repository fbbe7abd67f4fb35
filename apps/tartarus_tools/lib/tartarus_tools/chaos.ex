defmodule TartarusTools.Chaos do
  @moduledoc """
  The fault-injection harness behind `mix tartarus.chaos`: real BEAM nodes, agents migrating
  at random, nodes killed with SIGKILL and restarted, pairs of nodes partitioned and healed;
  at the end everything is healed and the agents are counted.

  ## What it measures

    * `duplicates` - extra copies: an agent id found on more than one host (must be 0);
    * `lost` - agents created and never found again;
    * `lost_on_dead_hosts` - of those, agents that were (as far as the driver knows) on a
      node when it was killed. Without persistence, killing a node loses its agents, so a
      correct platform has `lost == lost_on_dead_hosts`; with persistence (`persist: true`,
      every host checkpoints to its own data directory and is restarted on it) `lost` must
      be 0.

  The schedule of moves, kills and partitions is drawn from `seed`; the interleaving with
  the nodes' own timing is not deterministic (that is the point of a chaos run).

  ## How faults are made

    * a kill is `kill -9` of the node's OS process (`TartarusTools.Peer.kill/1`); the node is
      restarted under the same name a moment later (on the same data directory with
      persistence, empty without);
    * a partition gives two nodes wrong cookies for each other and closes their connection,
      so neither can reconnect until it is healed (`TartarusTools.Peer.partition/2`).
  """

  alias TartarusTools.Peer
  alias Tartarus.Examples.Echo

  @workers 8

  @doc """
  Runs a chaos experiment. Options: `:nodes` (default 8), `:agents` (500), `:migrations`
  (10_000), `:kills` (20), `:partitions` (20), `:persist` (false), `:seed` (1),
  `:progress` (a 1-arity fun called with the number of migrations attempted so far).
  Returns a map of results (see the moduledoc).
  """
  @spec run(keyword()) :: map()
  def run(opts) do
    n = Keyword.get(opts, :nodes, 8)
    agents = Keyword.get(opts, :agents, 500)
    migrations = Keyword.get(opts, :migrations, 10_000)
    kills = Keyword.get(opts, :kills, 20)
    partitions = Keyword.get(opts, :partitions, 20)
    persist = Keyword.get(opts, :persist, false)
    seed = Keyword.get(opts, :seed, 1)
    progress = Keyword.get(opts, :progress, fn _ -> :ok end)
    if n < 2, do: raise(ArgumentError, "a chaos run needs at least 2 nodes, got: #{n}")

    tag = "#{System.unique_integer([:positive])}"
    dir = Path.join(System.tmp_dir!(), "tartarus_chaos_#{tag}")
    names = for i <- 1..n, do: :"chaos#{i}_#{tag}"

    world = %{
      names: names,
      dir: dir,
      persist: persist,
      migrations: migrations,
      table: :ets.new(:chaos, [:public, :set])
    }

    t0 = System.monotonic_time(:millisecond)

    try do
      nodes = Enum.map(names, &start_node(world, &1))
      hosts = Enum.map(nodes, &{:h, &1})

      ids =
        for i <- 1..agents do
          host = Enum.at(hosts, rem(i, n))
          {:ok, id} = Tartarus.create_mobile_agent(host, Echo, i)
          :ets.insert(world.table, {{:loc, id}, host})
          id
        end

      rng = :rand.seed_s(:exsss, {seed, 7, 11})
      # Marks in successful migrations, spread over the first two thirds of the run.
      faults = schedule(div(migrations * 2, 3), kills, partitions, rng)
      # 1: migrations attempted, 2: migrations done, 3: 1 while a killed node restarts
      counter = :atomics.new(3, [])

      workers =
        for w <- 1..@workers do
          Task.async(fn -> worker(world, ids, hosts, migrations, counter, {seed, w}) end)
        end

      run_faults(world, faults, counter, nodes, progress, {seed, 0})
      Task.await_many(workers, :infinity)

      heal_all(world, nodes)
      settle(hosts)
      count(world, ids, hosts, counter, kills, partitions, persist, seed, n, t0)
    after
      for name <- names, do: Peer.kill(node_of(name))
      File.rm_rf(dir)
    end
  end

  # Migrations are spread over the run; each fault fires when the number of migrations
  # attempted so far reaches its mark.
  defp schedule(migrations, kills, partitions, rng) do
    {marks, _} =
      Enum.map_reduce(
        List.duplicate(:kill, kills) ++ List.duplicate(:partition, partitions),
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
    if :atomics.get(counter, 3) == 1, do: Process.sleep(20)

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
        move_one(world, id, dest, counter)
        loop(world, ids, hosts, migrations, counter, rng)
    end
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

    if :ets.member(world.table, {:dead, node}),
      do: :ets.insert(world.table, {{:on_dead, id}, true})
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
      Process.sleep(10)
      wait_for(counter, mark, migrations, progress)
    end
  end

  defp kill_and_restart(world, node, counter) do
    # The agents resident on the node (asked just before the kill, so an agent lost earlier
    # elsewhere is not excused by this kill) go down with it, unless persistence brings them
    # back; so do agents that arrive while the node is marked dead.
    :ets.insert(world.table, {{:dead, node}, true})

    for %{id: id} <- List.wrap(Tartarus.agents({:h, node})),
        do: :ets.insert(world.table, {{:on_dead, id}, true})

    Peer.kill(node)
    :atomics.put(counter, 3, 1)
    Process.sleep(100)
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

  defp partition_for_a_while(a, b) do
    try do
      Peer.partition(a, b)
    catch
      # One of them may be down (restarting): nothing to cut.
      _, _ -> :ok
    end

    Process.sleep(300)
    Peer.heal(a, b)
  end

  defp start_node(world, name) do
    {:ok, _pid, node} = Peer.start(name, link: false)

    host_opts =
      [migration_timeout: 1_000] ++
        if(world.persist, do: [data_dir: Path.join(world.dir, "#{name}")], else: [])

    {:ok, _} = :erpc.call(node, Tartarus, :start_host, [:h, host_opts])
    node
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
      Process.sleep(100)
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

  defp count(world, ids, hosts, counter, kills, partitions, persist, seed, n, t0) do
    found =
      Enum.flat_map(hosts, fn h -> h |> Tartarus.agents() |> List.wrap() |> Enum.map(& &1.id) end)

    freq = Enum.frequencies(found)
    duplicates = freq |> Map.values() |> Enum.map(&(&1 - 1)) |> Enum.sum()
    lost = Enum.reject(ids, &Map.has_key?(freq, &1))
    on_dead = Enum.count(lost, &:ets.member(world.table, {:on_dead, &1}))

    %{
      nodes: n,
      agents_start: length(ids),
      agents_end: map_size(freq),
      duplicates: duplicates,
      lost: length(lost),
      lost_on_dead_hosts: on_dead,
      migrations_done: :atomics.get(counter, 2),
      kills: kills,
      partitions: partitions,
      persist: persist,
      seed: seed,
      still_in_doubt: settle(hosts, 0),
      wall_ms: System.monotonic_time(:millisecond) - t0
    }
  end
end
