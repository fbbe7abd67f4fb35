Code.require_file("support/netns_bed.exs", __DIR__)
Code.require_file("support/release_session.exs", __DIR__)

defmodule Tartarus.NetnsTest do
  # The deployable release on a network of Linux namespaces (tag :netns; root only, see
  # Tartarus.NetnsBed and Tartarus.TestSupport.Tags.netns/0): nodes booted from their own
  # configuration files by `bin/tartarus start`, long names `tartarus@198.18.29.<i>`, TLS
  # distribution with per-node certificates, real link faults (`ip link set ... down`).
  # Figures (hand-off times, time to heal) are printed as `[netns] ...` lines.
  use ExUnit.Case, async: false

  alias Tartarus.NetnsBed, as: Bed
  import Tartarus.ReleaseSession

  @moduletag :netns
  @moduletag :peer
  @moduletag timeout: 900_000

  @nodes 6
  @impostor 9
  @plain 10
  # The node booted from rel/node.exs.example (test (f)).
  @example 7
  @ticktime 4

  # Each test compiles its own agent module, so that no test's module is already shipped.
  defp source(mod) do
    """
    defmodule #{mod} do
      use Tartarus.Agent
      def init(tag), do: {:stay, %{tag: tag, log: []}}
      def handle_arrival(ctx, s), do: {:stay, %{s | log: [ctx.host | s.log]}}
      def handle_message(:info, from, s) do
        Tartarus.Agent.reply(from, %{node: node(), log: s.log, hops: Tartarus.Agent.hops(), tag: s.tag})
        {:stay, s}
      end
      def handle_message(_, _from, s), do: {:stay, s}
    end
    """
  end

  # Movers on node 1: each agent goes back and forth between h1 and h2 until told to stop;
  # the boss counts the outcome of every move and reports the counts when asked.
  @boss """
  defmodule Tt29Boss do
    def start(ids, h1, h2) do
      pid = spawn(fn -> init(ids, h1, h2) end)
      Process.register(pid, :tt29_boss)
      :ok
    end

    defp init(ids, h1, h2) do
      me = self()
      movers = for id <- ids, do: spawn(fn -> move(id, h1, [h2, h1], me) end)
      loop(movers, %{}, 0)
    end

    defp move(id, h1, [dest, other], boss) do
      receive do
        :stop -> send(boss, :done)
      after
        0 ->
          r = try do Tartarus.move({id, h1}, dest) catch k, e -> {k, e} end
          send(boss, {:moved, r})
          move(id, h1, [other, dest], boss)
      end
    end

    defp loop(movers, counts, done) do
      receive do
        {:moved, r} ->
          key = if r == :ok, do: :ok, else: r |> inspect() |> String.slice(0, 60)
          loop(movers, Map.update(counts, key, 1, &(&1 + 1)), done)
        :stop ->
          Enum.each(movers, &send(&1, :stop))
          loop(movers, counts, done)
        :done when done + 1 == length(movers) ->
          receive do
            {:report, from} -> send(from, {:report, counts})
          end
        :done ->
          loop(movers, counts, done + 1)
      end
    end
  end
  """

  # The chaos workload, run on the control node: workers each move a random agent from the
  # host it was last seen on to a random other host (`:erpc` to that host's node); an agent
  # whose move failed is looked for on every host before it is moved again.
  @chaos """
  defmodule Tt29Chaos do
    def start(ids, hosts, workers, seed) do
      table = :ets.new(:tt29_chaos, [:public, :set])
      for id <- ids, do: :ets.insert(table, {id, hd(hosts)})
      :persistent_term.put(:tt29_stop, false)
      parent = self()
      pids = for w <- 1..workers do
        spawn(fn ->
          :rand.seed(:exsss, {seed, w, 29})
          send(parent, {:worker_done, work(table, ids, hosts, %{})})
        end)
      end
      :persistent_term.put(:tt29_workers, {table, pids})
      :ok
    end

    def stop do
      :persistent_term.put(:tt29_stop, true)
      {_table, pids} = :persistent_term.get(:tt29_workers)
      Enum.reduce(pids, %{}, fn _, acc ->
        receive do
          {:worker_done, counts} -> Map.merge(acc, counts, fn _, a, b -> a + b end)
        after
          120_000 -> Map.update(acc, :worker_timeout, 1, &(&1 + 1))
        end
      end)
    end

    defp work(table, ids, hosts, counts) do
      if :persistent_term.get(:tt29_stop) do
        counts
      else
        id = Enum.random(ids)
        counts =
          case :ets.lookup(table, id) do
            [{^id, :unknown}] -> locate(table, id, hosts, counts)
            [{^id, {_, node} = at}] ->
              dest = Enum.random(hosts -- [at])
              r =
                try do
                  :erpc.call(node, Tartarus, :move, [{id, at}, dest], 20_000)
                catch
                  kind, e -> {kind, e}
                end
              if r == :ok, do: :ets.insert(table, {id, dest}), else: :ets.insert(table, {id, :unknown})
              key = if r == :ok, do: :moved, else: r |> inspect() |> String.slice(0, 50)
              Map.update(counts, key, 1, &(&1 + 1))
          end
        work(table, ids, hosts, counts)
      end
    end

    defp locate(table, id, hosts, counts) do
      found =
        Enum.find(hosts, fn {_, node} = h ->
          try do
            Enum.any?(:erpc.call(node, Tartarus, :agents, [h], 5_000), &(&1.id == id))
          catch
            _, _ -> false
          end
        end)
      if found, do: :ets.insert(table, {id, found}), else: Process.sleep(200)
      Map.update(counts, :located, 1, &(&1 + 1))
    end
  end
  """

  setup_all do
    bed = Bed.plan(@nodes, [@impostor, @plain, @example])

    on_exit(fn ->
      Bed.destroy(bed)
      leftovers = Bed.leftovers(bed)
      if leftovers != [], do: raise("the bed left: #{inspect(leftovers)}")
    end)

    bed = Bed.create!(bed)

    for i <- 1..@nodes, do: Bed.start_node!(bed, i, node_config(i))

    for i <- 1..@nodes, do: Bed.await_up!(bed, i)
    %{bed: bed}
  end

  # Each node links to the one before it, and runs a small net_ticktime.
  defp node_config(i) do
    neighbours = if i > 1, do: [{:"h#{i - 1}", "tartarus@#{Bed.ip(i - 1)}"}], else: []
    [neighbours: neighbours, net_ticktime: @ticktime]
  end

  defp nodes, do: for(i <- 1..@nodes, do: Bed.node_name(i))
  defp hosts, do: for(i <- 1..@nodes, do: {:"h#{i}", Bed.node_name(i)})

  test "(a) an agent born on node 1, whose module only node 1 has, crosses every node over TLS and comes back",
       %{bed: bed} do
    r =
      Bed.ctl!(bed, """
      nodes = #{inspect(nodes())}
      hosts = #{inspect(hosts())}
      [n1 | others] = nodes
      [h1 | _] = hosts
      {:ok, [mod]} = :erpc.call(n1, Tartarus, :compile_string, [#{lit(source("Tt29WalkerA"))}])
      before = for n <- others, do: :erpc.call(n, :code, :is_loaded, [mod])
      {:ok, id} = :erpc.call(n1, Tartarus, :create_mobile_agent, [:h1, mod, :a])
      moves =
        for h <- tl(hosts) ++ [h1] do
          {us, result} = :erpc.call(n1, :timer, :tc, [Tartarus, :move, [{id, h1}, h]])
          {h, us, result}
        end
      {:ok, info} = :erpc.call(n1, Tartarus, :request, [{id, h1}, :info])
      shipped = for n <- others, do: :erpc.call(n, :code, :is_loaded, [mod])
      protocols =
        for n <- nodes do
          {:ok, infos} = :erpc.call(n, :net_kernel, :nodes_info, [])
          {n, for({peer, i} <- infos, do: {peer, elem(i[:address], 3)})}
        end
      %{before: before, moves: moves, info: info, shipped: shipped, protocols: protocols, h1: h1}
      """)

    assert Enum.all?(r.before, &(&1 == false))
    assert for({_, _, result} <- r.moves, do: result) == List.duplicate(:ok, @nodes)
    assert r.info.node == Bed.node_name(1)
    assert Enum.reverse(r.info.log) == tl(hosts()) ++ [r.h1]
    assert r.info.hops == @nodes
    assert Enum.all?(r.shipped, &match?({:file, ~c"tartarus:shipped"}, &1))

    # Every distribution connection of every node runs over TLS, under long names.
    for {_node, peers} <- r.protocols, {peer, protocol} <- peers do
      assert protocol == :tls
      assert Atom.to_string(peer) =~ ~r/@198\.18\.29\.\d+$/
    end

    ms = for {_, us, _} <- r.moves, do: us / 1000

    IO.puts(
      "\n[netns] (a) hand-off across namespaces over TLS, ms per move (tour of #{@nodes} nodes, ordered from node 1): " <>
        Enum.map_join(ms, ", ", &:erlang.float_to_binary(&1, decimals: 1)) <>
        "; median #{:erlang.float_to_binary(median(ms), decimals: 1)}"
    )
  end

  test "(b) a separately started shell node attaches over TLS with its own certificate and moves an agent",
       %{bed: bed} do
    # A one-off `elixir` VM, as a user's laptop would run it: long name, the TLS flags of
    # `Tartarus.Security.TLSDist.erl_flags/2` for its own certificate, `:erpc` to node 2.
    {:ok, id} =
      Bed.ctl!(bed, """
      {:ok, [mod]} = :erpc.call(#{inspect(Bed.node_name(2))}, Tartarus, :compile_string, [#{lit(source("Tt29WalkerB"))}])
      :erpc.call(#{inspect(Bed.node_name(2))}, Tartarus, :create_mobile_agent, [:h2, mod, :b])
      """)

    {out, status} =
      Bed.shell(bed, """
      n2 = #{inspect(Bed.node_name(2))}
      h3 = #{inspect({:h3, Bed.node_name(3)})}
      IO.puts("moved: " <> inspect(:erpc.call(n2, Tartarus, :move, [{#{inspect(id)}, :h2}, h3])))
      {:ok, info} = :erpc.call(n2, Tartarus, :request, [{#{inspect(id)}, :h2}, :info])
      IO.puts("now on: " <> inspect(info.node))
      {:ok, i} = :erpc.call(n2, :net_kernel, :node_info, [node()])
      IO.puts("protocol: " <> inspect(elem(i[:address], 3)))
      """)

    assert status == 0, out
    assert out =~ "moved: :ok"
    assert out =~ "now on: #{inspect(Bed.node_name(3))}"
    assert out =~ "protocol: :tls"
  end

  test "(c) a node with a certificate for another name, and a plain-TCP node, are refused",
       %{bed: bed} do
    certs = bed.certs
    n1 = "tartarus@#{Bed.ip(1)}"

    # The impostor runs as tartarus@198.18.29.9 with node 1's certificate and key; the plain
    # node has no TLS at all. Both try to link to node 1 every 2 s (their neighbours).
    Bed.start_node!(bed, @impostor,
      tls: [
        cert: Path.join(certs, "#{n1}.pem"),
        key: Path.join(certs, "#{n1}.key"),
        ca: Path.join(certs, "ca.pem")
      ],
      neighbours: [h1: n1]
    )

    Bed.start_node!(bed, @plain, tls: nil, cookie: "tartarus", neighbours: [h1: n1])
    Bed.await_up!(bed, @impostor)
    Bed.await_up!(bed, @plain)
    # Several of their link attempts.
    Process.sleep(8_000)

    r =
      Bed.ctl!(bed, """
      n1 = #{inspect(Bed.node_name(1))}
      %{
        impostor: Node.ping(#{inspect(Bed.node_name(@impostor))}),
        plain: Node.ping(#{inspect(Bed.node_name(@plain))}),
        genuine: Node.ping(#{inspect(Bed.node_name(2))}),
        n1_nodes: :erpc.call(n1, Node, :list, []),
        n1_neighbours: :erpc.call(n1, Tartarus, :neighbours, [:h1])
      }
      """)

    assert r.genuine == :pong
    assert r.impostor == :pang
    assert r.plain == :pang
    refute Bed.node_name(@impostor) in r.n1_nodes
    refute Bed.node_name(@plain) in r.n1_nodes
    refute Enum.any?(r.n1_neighbours, fn {h, _} -> h in [:"h#{@impostor}", :"h#{@plain}"] end)

    # Both did run and did try.
    {out9, nil} = Bed.output(bed, @impostor)
    {out10, nil} = Bed.output(bed, @plain)
    assert out9 =~ "running"
    assert out10 =~ "running"
    Bed.kill_node(bed, @impostor)
    Bed.kill_node(bed, @plain)
  end

  test "(e) a partition longer than net_ticktime heals, and in-doubt hand-offs resolve without a duplicate",
       %{bed: bed} do
    agents = 40
    [n1, n2 | _] = nodes()
    [h1, h2 | _] = hosts()

    ids =
      Bed.ctl!(bed, """
      {:ok, [mod]} = :erpc.call(#{inspect(n1)}, Tartarus, :compile_string, [#{lit(source("Tt29WalkerE"))}])
      for i <- 1..#{agents} do
        {:ok, id} = :erpc.call(#{inspect(n1)}, Tartarus, :create_mobile_agent, [:h1, mod, i])
        id
      end
      """)

    # One hand-off put in doubt on purpose: node 1's source stops just before it sends
    # `commit` (the `Tartarus.Fault` point `:committing`); once node 2's link is down it
    # goes on, and its commit goes into the cut: node 2 holds a prepared copy it cannot
    # settle until the partition heals.
    x =
      Bed.ctl!(bed, """
      n1 = #{inspect(n1)}
      {:ok, x} = :erpc.call(n1, Tartarus, :create_mobile_agent, [:h1, Tt29WalkerE, :x])
      :ok = :erpc.call(n1, Tartarus.Fault, :install, [:committing, {:once, {:pause, self()}}])
      _ = :erpc.call(n1, :erlang, :spawn, [Tartarus, :move, [{x, #{inspect(h1)}}, #{inspect(h2)}]])
      receive do
        {:fault_paused, :committing, pid, _} -> :persistent_term.put(:tt29_paused, pid)
      after
        120_000 -> raise "the hand-off never reached :committing"
      end
      x
      """)

    :ok =
      Bed.ctl!(bed, """
      n1 = #{inspect(n1)}
      [_ | _] = :erpc.call(n1, Code, :compile_string, [#{lit(@boss)}])
      :erpc.call(n1, Tt29Boss, :start, [#{lit(ids)}, #{inspect(h1)}, #{inspect(h2)}])
      """)

    Process.sleep(3_000)
    Bed.link(bed, 2, :down)
    t_cut = System.monotonic_time(:millisecond)
    Process.sleep(500)

    :ok =
      Bed.ctl!(bed, """
      pid = :persistent_term.get(:tt29_paused)
      send(pid, {:fault_continue, pid})
      :ok
      """)

    # While the link is down: how many copies node 1 holds in doubt (hand-offs from node 2
    # whose commit cannot arrive), at most, and whether node 1 has seen node 2 go down.
    during =
      for _ <- 1..10 do
        Process.sleep(1_500)

        Bed.ctl!(
          bed,
          "{:erpc.call(#{inspect(n1)}, Tartarus.Host, :call, [#{inspect(h1)}, :paused]), " <>
            "#{inspect(n2)} in :erpc.call(#{inspect(n1)}, Node, :list, [])}"
        )
      end

    Bed.ctl!(bed, "send({:tt29_boss, #{inspect(n1)}}, :stop)")
    # Movers blocked in a hand-off return after the migration timeout.
    Process.sleep(6_000)
    partition_ms = System.monotonic_time(:millisecond) - t_cut
    Bed.link(bed, 2, :up)
    t_up = System.monotonic_time(:millisecond)

    # Healed: every agent answers from exactly one host and no copy is paused.
    census = """
    ids = #{lit([x | ids])}
    hosts = #{inspect([h1, h2])}
    residents = for {_, n} = h <- hosts, a <- :erpc.call(n, Tartarus, :agents, [h]), a.id in ids, do: {a.id, h}
    paused = for {_, n} = h <- hosts, do: :erpc.call(n, Tartarus.Host, :call, [h, :paused])
    %{residents: residents, paused: paused, connected: #{inspect(n2)} in :erpc.call(#{inspect(n1)}, Node, :list, [])}
    """

    {healed, census_result} = await_healed(bed, census, [x | ids], 120_000)
    paused_after = Process.get(:max_paused, 0)
    heal_ms = System.monotonic_time(:millisecond) - t_up

    send_report =
      Bed.ctl!(
        bed,
        "send({:tt29_boss, #{inspect(n1)}}, {:report, self()}); receive do {:report, c} -> c after 30_000 -> :no_report end"
      )

    max_paused =
      during |> Enum.map(&elem(&1, 0)) |> Enum.filter(&is_integer/1) |> Enum.max(fn -> 0 end)

    saw_down = Enum.any?(during, &(elem(&1, 1) == false))

    IO.puts(
      "\n[netns] (e) link of node 2 down #{partition_ms} ms (net_ticktime #{@ticktime} s): node 1 saw node 2 down: #{saw_down}; " <>
        "copies in doubt on node 1 during the cut at most #{max_paused}, on nodes 1-2 after it at most #{paused_after}; healed (#{agents} agents and the one held in doubt, each on one host, none paused) #{heal_ms} ms after the link came up; " <>
        "move outcomes: #{inspect(send_report)}"
    )

    assert saw_down, "node 1 never saw node 2 go down: #{inspect(during)}"
    assert healed, "not healed: #{inspect(census_result)}"
    counts = Enum.frequencies_by(census_result.residents, &elem(&1, 0))
    assert map_size(counts) == agents + 1
    # The hand-off in doubt was committed by its source: the agent runs at node 2, once.
    assert [{^x, ^h2}] = Enum.filter(census_result.residents, &(elem(&1, 0) == x))
    assert Enum.all?(counts, fn {_, c} -> c == 1 end)
  end

  test "(f) the documented configuration on the bed: BLE on a tty and Where am I; GPIO without hardware refused; the operator over TLS (remote, rpc, pid, stop); refused shells say why",
       %{bed: bed} do
    i = @example
    name = "tartarus@#{Bed.ip(i)}"
    n1 = Bed.node_name(1)
    ndir = Path.join(bed.dir, "n#{i}")
    # The node's own certificate directory (the bed's CA; the test swaps the operator's
    # certificate there): ca.pem, its certificate and the operator's.
    certs = Path.join(ndir, "certs")
    File.mkdir_p!(certs)

    for f <- ["ca.pem", "#{name}.pem", "#{name}.key", "operator.pem", "operator.key"],
        do: File.cp!(Path.join(bed.certs, f), Path.join(certs, f))

    tty = Path.join(ndir, "hm10")
    socat = socat!(tty)

    try do
      paths = example_paths(name, certs, "operator", {:h1, Atom.to_string(n1)}, tty, ndir)

      # GPIO pins on a node with no GPIO hardware backend: the boot stops in one line.
      gpio =
        from_example!(
          ndir,
          paths ++
            [
              {"#{inspect(tty)}}\n", "#{inspect(tty)}},\n"},
              {"# io: {Tartarus.Plugin.GPIO", "io: {Tartarus.Plugin.GPIO"},
              {", backend: MyBackend}", "}"}
            ],
          "gpio.exs"
        )

      {out, 1} = Bed.release_cmd(bed, i, gpio, ["start"])
      assert [line] = String.split(out, "\n", trim: true)

      assert line =~
               "tartarus: bad configuration #{gpio}: plugins: io: Tartarus.Plugin.GPIO: no GPIO backend on this node for pins led (line 17)"

      # The example adapted in paths and names only boots, BLE on the socat tty.
      path = from_example!(ndir, paths)
      Bed.launch(bed, i, path, ndir, "start")
      Bed.await_up!(bed, i)
      {out, nil} = Bed.output(bed, i)

      assert out =~
               "running; plugins: temp (Tartarus.Plugin.SimSensor), beacon (Tartarus.Plugin.Serial)"

      # The HM-10 hears the tag; LATS on the node (the example's services:) answers Where am I.
      tag = TartarusLats.Beacon.tag_id(beacon())

      for _ <- 1..6 do
        hear(socat)
        Process.sleep(700)
      end

      assert eventually(fn ->
               hear(socat)
               {out, 0} = Bed.release_cmd(bed, i, path, ["rpc", where_am_i(:pi1, tag)])
               out =~ "{:in_zone, :pi1}"
             end)

      # pid: the node's VM, in its namespace.
      {pid, 0} = Bed.release_cmd(bed, i, path, ["pid"])
      assert String.trim(pid) in Bed.ns_pids(bed, i)
      assert File.read!("/proc/#{String.trim(pid)}/cmdline") =~ "beam"

      # The operator's shell through a pty, in the node's namespace: it evaluates on the node
      # and moves an agent to node 1, across the bed's network.
      remote =
        pty!(
          Bed.in_ns(bed, i, Path.join(bed.root, "bin/tartarus remote")),
          Bed.release_env(path, ndir)
        )

      await_pty(remote, "iex(#{name})1>")

      Port.command(
        remote,
        ~S|{:ok, [m]} = Tartarus.compile_string("defmodule Tt41Op do use Tartarus.Agent; def init(s), do: {:stay, s} end"); {:ok, id} = Tartarus.create_mobile_agent(:pi1, m, :x); IO.puts("moved: #{inspect(Tartarus.move({id, :pi1}, {:h1, :"| <>
          "#{n1}" <> ~S|"}))} from #{node()}")| <> "\n"
      )

      await_pty(remote, "moved: :ok from #{name}")
      quit_pty(remote)

      moved =
        Bed.ctl!(bed, """
        n1 = #{inspect(n1)}
        {:erpc.call(n1, :code, :is_loaded, [Tt41Op]),
         Enum.count(:erpc.call(n1, Tartarus, :agents, [{:h1, n1}]), &(&1.module == Tt41Op))}
        """)

      assert moved == {{:file, ~c"tartarus:shipped"}, 1}

      assert {"on #{name}\n", 0} ==
               Bed.release_cmd(bed, i, path, ["rpc", ~S|IO.puts("on #{node()}")|])

      # An operator certificate from another CA: one line, before any connection.
      other = Path.join(ndir, "other")
      {:ok, _} = Tartarus.Security.Certs.generate(other, nodes: ["operator"], hosts: [Bed.ip(i)])
      op = Path.join(certs, "operator.pem")
      File.rename!(op, op <> ".keep")
      File.cp!(Path.join(other, "operator.pem"), op)
      {out, 1} = Bed.release_cmd(bed, i, path, ["rpc", "1"])
      assert [line] = String.split(out, "\n", trim: true)

      assert line =~
               "tartarus: rpc: refused before connecting: #{op} was not issued by this node's CA"

      File.rename!(op <> ".keep", op)

      # A workstation's iex --remsh (in the control namespace) with the documented flags:
      # its own certificate, -proto_dist tartarus_tls from the release's tartarus ebin.
      ws = Bed.ip(Bed.ctl_index())
      ebin = Path.wildcard(Path.join(bed.root, "lib/tartarus-*/ebin")) |> hd()

      remsh = fn me, optfile ->
        Bed.in_ns(
          bed,
          Bed.ctl_index(),
          "iex --name #{me} --cookie tartarus --erl '-proto_dist tartarus_tls -ssl_dist_optfile #{optfile} -pa #{ebin} -connect_all false' --remsh #{name}"
        )
      end

      shell = pty!(remsh.("me@#{ws}", Path.join(bed.certs, "me@#{ws}.ssl_dist.conf")), [])
      await_pty(shell, "iex(#{name})1>")
      Port.command(shell, "Tartarus.read_plugin(:pi1, :temp, :value) |> elem(0)\n")
      await_pty(shell, ":ok")
      quit_pty(shell)

      # Refused shells say why, on the shell's side, in one line: a certificate of another CA
      # (trusting the node's), and a name its certificate does not name.
      {:ok, _} =
        Tartarus.Security.Certs.generate(Path.join(other, "ws"), nodes: ["me@#{ws}"], hosts: [ws])

      File.cp!(Path.join(bed.certs, "ca.pem"), Path.join([other, "ws", "ca.pem"]))
      foreign = Path.join([other, "ws", "me@#{ws}.ssl_dist.conf"])
      own = Path.join(bed.certs, "me@#{ws}.ssl_dist.conf")

      for {me, optfile, cause} <- [
            {"me@#{ws}", foreign,
             "this node's certificate #{Path.join([other, "ws", "me@#{ws}.pem"])} was not issued by the node's CA (TLS alert unknown_ca from the node)"},
            {"you@#{ws}", own,
             "the node admits only the names this node's certificate #{Path.join(bed.certs, "me@#{ws}.pem")} names (me@#{ws}), and this node runs as you@#{ws}"}
          ] do
        {out, _} = pty_exit(pty!(remsh.(me, optfile), []))
        assert out =~ "Could not contact remote node #{name}, reason: :nodedown"

        assert [line] =
                 out
                 |> String.split(~r/\R/)
                 |> Enum.map(&String.trim/1)
                 |> Enum.filter(&(&1 =~ "tartarus_tls:"))
                 |> Enum.uniq()

        assert line == "tartarus_tls: no connection from #{me} to #{name}: #{cause}"
      end

      assert {_, 0} = Bed.release_cmd(bed, i, path, ["stop"])

      assert eventually(fn -> match?({_, 0}, Bed.output(bed, i)) end),
             "the node did not stop: #{inspect(Bed.output(bed, i))}"
    after
      stop_ptys()
      stop_port(socat)
      Bed.kill_node(bed, i)
    end
  end

  @tag :long
  test "(d) 20 link cuts and 5 SIGKILLs with restarts on 6 nodes with persistence: no agent lost, none duplicated",
       %{bed: bed} do
    agents = 60
    hosts = hosts()
    [n1 | _] = nodes()
    seed = 29

    # The chaos harness's agent (`TartarusTools.Chaos.Counter`), which every node has on its
    # code path, as in `mix tartarus.chaos`: a node restarted from its data directory restores
    # an agent's state, not code that reached it by shipping (which lives in memory only), so
    # an agent of a module compiled on node 1 would not survive its host's SIGKILL unless its
    # module is installed (see docs/devices.md).
    ids =
      Bed.ctl!(bed, """
      sink = spawn(fn -> Stream.repeatedly(fn -> receive do _ -> :ok end end) |> Stream.run() end)
      for i <- 1..#{agents} do
        {:ok, id} = :erpc.call(#{inspect(n1)}, Tartarus, :create_mobile_agent, [:h1, TartarusTools.Chaos.Counter, {i, sink}])
        id
      end
      """)

    :ok =
      Bed.ctl!(bed, """
      [_ | _] = Code.compile_string(#{lit(@chaos)})
      Tt29Chaos.start(#{lit(ids)}, #{inspect(hosts)}, 6, #{seed})
      """)

    # The faults, one at a time, in an order drawn from the seed: a cut takes a node's link
    # down for 1 to 7 s (net_ticktime is 4 s: some cuts outlast it, some do not); a kill is
    # SIGKILL of the node's VM and, half a second later, `bin/tartarus start` again on the
    # same configuration and data directory.
    :rand.seed(:exsss, {seed, 0, 0})
    faults = Enum.shuffle(List.duplicate(:cut, 20) ++ List.duplicate(:kill, 5))
    t0 = System.monotonic_time(:millisecond)

    log =
      for fault <- faults do
        i = Enum.random(1..@nodes)
        Process.sleep(500 + :rand.uniform(1_000))

        case fault do
          :cut ->
            ms = 1_000 + :rand.uniform(6_000)
            Bed.link(bed, i, :down)
            Process.sleep(ms)
            Bed.link(bed, i, :up)
            {:cut, i, ms}

          :kill ->
            # Not waited for: the next faults go on while it boots (and may hit it).
            Bed.kill_node(bed, i)
            Process.sleep(500)
            Bed.start_node!(bed, i, node_config(i))
            {:kill, i}
        end
      end

    for i <- 1..@nodes, do: Bed.await_up!(bed, i)

    faults_ms = System.monotonic_time(:millisecond) - t0
    counts = Bed.ctl!(bed, "Tt29Chaos.stop()")
    t_stop = System.monotonic_time(:millisecond)

    census = """
    ids = MapSet.new(#{lit(ids)})
    hosts = #{inspect(hosts)}
    found =
      for {_, n} = h <- hosts,
          a <- (try do :erpc.call(n, Tartarus, :agents, [h], 10_000) catch _, _ -> [] end),
          MapSet.member?(ids, a.id),
          do: {a.id, h}
    paused = for {_, n} = h <- hosts, do: (try do :erpc.call(n, Tartarus.Host, :call, [h, :paused], 10_000) catch _, e -> {:unreachable, e} end)
    %{residents: found, paused: paused}
    """

    {healed, result} = await_healed(bed, census, ids, 180_000)
    settle_ms = System.monotonic_time(:millisecond) - t_stop
    per_id = Enum.frequencies_by(result.residents, &elem(&1, 0))
    lost = Enum.count(ids, &(not Map.has_key?(per_id, &1)))
    duplicated = Enum.count(per_id, fn {_, c} -> c > 1 end)

    IO.puts(
      "\n[netns] (d) #{@nodes} nodes, #{agents} agents, persistence: " <>
        "#{Enum.count(log, &match?({:cut, _, _}, &1))} link cuts, #{Enum.count(log, &match?({:kill, _}, &1))} SIGKILL+restart in #{faults_ms} ms; " <>
        "census: #{lost} lost, #{duplicated} duplicated, paused #{inspect(result.paused)}, settled #{settle_ms} ms after the workload stopped; " <>
        "moves: #{inspect(counts)}; faults: #{inspect(log)}"
    )

    assert healed, "not settled: #{inspect(result)}"
    assert lost == 0
    assert duplicated == 0
  end

  defp await_healed(bed, census, ids, ms) do
    deadline = System.monotonic_time(:millisecond) + ms
    await_healed(bed, census, ids, deadline, nil)
  end

  defp await_healed(bed, census, ids, deadline, last) do
    r = Bed.ctl(bed, census)

    case r do
      {:ok, %{residents: residents, paused: paused} = c} ->
        in_doubt = paused |> Enum.filter(&is_integer/1) |> Enum.sum()
        Process.put(:max_paused, max(Process.get(:max_paused, 0), in_doubt))

        ok =
          Enum.all?(paused, &(&1 == 0)) and length(residents) == length(ids) and
            MapSet.new(residents, &elem(&1, 0)) == MapSet.new(ids)

        cond do
          ok -> {true, c}
          System.monotonic_time(:millisecond) > deadline -> {false, c}
          true -> retry(bed, census, ids, deadline, c)
        end

      other ->
        if System.monotonic_time(:millisecond) > deadline,
          do: {false, last || other},
          else: retry(bed, census, ids, deadline, last)
    end
  end

  defp retry(bed, census, ids, deadline, last) do
    Process.sleep(200)
    await_healed(bed, census, ids, deadline, last)
  end

  # A term as Elixir source, whole (for code evaluated on the control node).
  defp lit(term), do: inspect(term, limit: :infinity, printable_limit: :infinity)

  defp median(xs) do
    s = Enum.sort(xs)
    n = length(s)

    if rem(n, 2) == 1,
      do: Enum.at(s, div(n, 2)),
      else: (Enum.at(s, div(n, 2) - 1) + Enum.at(s, div(n, 2))) / 2
  end
end
