defmodule TartarusEmu.DashboardBench do
  @moduledoc """
  What the web dashboard costs and how it behaves at scale (`mix tartarus.dashboard.bench`).

  1. **Migration throughput with and without a page.** An emulated ring of `:hosts` hosts
     (or of each of `:sizes`)
     with `:agents` Echo agents, each moved `:moves` times around the ring by its own
     driver process (`Tartarus.move/2`), timed. Three conditions, interleaved in each of
     `:rounds` rounds: `none` (no dashboard), `dashboard` (running, nobody watching) and
     `page` (a real headless Chromium showing the page, live, if Chromium is installed;
     otherwise a raw server-sent-events client, and `page_client` says so). Reports each
     condition's migrations per second (median over rounds) and the ratios to `none`,
     plus what the page received (events, batches) and what the feed dropped. With
     `:health` (the default) the dashboard conditions also run the health sampler; it is
     stopped for `none`, so the baseline is charged nothing of it.
  2. **10,000 emulated hosts.** A `:big_rows` x `:big_cols` grid in a fresh BEAM node
     (large `+P`/`+e`) with `:big_agents` agents, some of them moving, and a dashboard:
     sizes and times of the API's answers (first, cold, and then cached), and the page in
     Chromium (time to ready, whether it aggregated, how many groups it drew).

  Returns a JSON-encodable map. Timings are wall-clock and vary between machines and runs;
  the moves, hosts and agents are the same for the same options.
  """

  alias TartarusEmu.{Network, Topology}
  alias Tartarus.Clock
  alias Tartarus.MachineClock
  require Tartarus.MachineClock
  alias TartarusDashboard.Health
  alias TartarusTools.Browser

  @schema [
    hosts: [type: :pos_integer, default: 8, doc: "hosts in the throughput ring"],
    sizes: [
      type: :any,
      doc:
        "measure throughput at each of these host counts instead (a list, or a string like `\"1,10000\"`; 1 host: each move a hop to the same host)"
    ],
    health: [
      type: :boolean,
      default: true,
      doc: "the dashboard samples the node's health (`TartarusDashboard.Health`) while it runs"
    ],
    agents: [type: :pos_integer, default: 16, doc: "agents moving concurrently"],
    moves: [type: :pos_integer, default: 500, doc: "moves per agent per run"],
    rounds: [type: :pos_integer, default: 5, doc: "rounds (each runs the three conditions)"],
    big: [type: :boolean, default: true, doc: "also measure 10,000 hosts"],
    big_rows: [type: :pos_integer, default: 100, doc: "rows of the big grid"],
    big_cols: [type: :pos_integer, default: 100, doc: "columns of the big grid"],
    big_agents: [type: :pos_integer, default: 1_000, doc: "agents on the big grid"],
    quiet: [
      type: :boolean,
      default: false,
      doc: "no progress line (it is drawn only on a terminal in any case)"
    ]
  ]

  @doc "The options' schema."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc "Runs both parts (see the moduledoc) and returns the figures."
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts \\ []) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusEmu.DashboardBench"),
         {:ok, sizes} <- sizes(opts) do
      by_size = Enum.map(sizes, &throughput(Keyword.put(opts, :hosts, &1)))
      big = if opts[:big], do: big(opts), else: nil

      {:ok,
       %{
         throughput: hd(by_size),
         throughput_by_hosts: by_size,
         health_sampling: opts[:health],
         big: big,
         chromium: Browser.executable() != nil
       }}
    end
  end

  defp sizes(opts) do
    case opts[:sizes] do
      nil ->
        {:ok, [opts[:hosts]]}

      list when is_list(list) ->
        if list != [] and Enum.all?(list, &(is_integer(&1) and &1 > 0)),
          do: {:ok, list},
          else: {:error, "sizes: expected positive integers, got: #{inspect(list)}"}

      text when is_binary(text) ->
        text
        |> String.split(",", trim: true)
        |> Enum.map(&Integer.parse(String.trim(&1)))
        |> Enum.map(fn
          {n, ""} -> n
          _ -> nil
        end)
        |> then(&sizes(Keyword.put(opts, :sizes, &1)))
    end
  end

  # -- 1. throughput ---------------------------------------------------------------------

  # One host: a topology of one node (each move a hop to the same host); two: a line.
  defp ring(1), do: Topology.new([:h1], [])
  defp ring(2), do: Topology.line(2)
  defp ring(n), do: Topology.ring(n)

  defp throughput(opts) do
    t_net = Clock.machine_time(:millisecond)
    {:ok, net} = Network.start(ring(opts[:hosts]))
    network_ms = Clock.machine_time(:millisecond) - t_net
    hosts = net |> Network.host_list() |> List.to_tuple()
    n = tuple_size(hosts)

    agents =
      for i <- 0..(opts[:agents] - 1) do
        home = rem(i, n)

        {:ok, id} = Tartarus.create_mobile_agent(elem(hosts, home), Tartarus.Examples.Echo, nil)

        {id, home}
      end

    browser =
      case Browser.executable() && Browser.start() do
        {:ok, b} -> b
        _ -> nil
      end

    try do
      # One warm-up run (code loaded, caches filled), not counted.
      {agents, _} = drive(agents, hosts, opts[:moves])

      # What, k of n, elapsed, ETA: one unit per (round, condition).
      progress =
        TartarusTools.Progress.new(opts[:rounds] * 3,
          label: "dashboard bench: runs (rounds x 3 conditions)",
          quiet: opts[:quiet]
        )

      {_agents, runs, progress} =
        Enum.reduce(1..opts[:rounds], {agents, [], progress}, fn round, acc ->
          Enum.reduce([:none, :dashboard, :page], acc, fn cond, {agents, runs, progress} ->
            {agents, run} = condition(cond, net, agents, hosts, opts, browser)
            run = Map.merge(run, %{round: round, condition: cond})
            {agents, [run | runs], TartarusTools.Progress.advance(progress)}
          end)
        end)

      TartarusTools.Progress.finish(progress)

      runs = Enum.reverse(runs)

      median = fn c ->
        runs
        |> Enum.filter(&(&1.condition == c))
        |> Enum.map(& &1.migrations_per_s)
        |> TartarusTools.Stats.median()
      end

      none = median.(:none)

      %{
        hosts: opts[:hosts],
        network_ms: network_ms,
        health_sampling: opts[:health],
        sample_cost_us: sample_cost(runs),
        agents: opts[:agents],
        moves_per_run: opts[:agents] * opts[:moves],
        rounds: opts[:rounds],
        page_client: if(browser, do: "chromium", else: "sse-socket"),
        median_migrations_per_s: %{
          none: none,
          dashboard: median.(:dashboard),
          page: median.(:page)
        },
        ratio_dashboard_to_none: Float.round(median.(:dashboard) / none, 3),
        ratio_page_to_none: Float.round(median.(:page) / none, 3),
        runs: runs
      }
    after
      if browser, do: Browser.stop(browser)
      Network.stop(net)
    end
  end

  defp condition(:none, _net, agents, hosts, opts, _b) do
    # The health sampler is node-wide and outlives a dashboard: the baseline runs without it.
    Health.stop()
    {agents, us} = drive(agents, hosts, opts[:moves])
    {agents, rate(opts, us)}
  end

  defp condition(:dashboard, net, agents, hosts, opts, _b) do
    Health.stop()
    {:ok, dash} = TartarusEmu.Dashboard.start_link(net, health: opts[:health])
    {agents, us} = drive(agents, hosts, opts[:moves])
    costs = sampled_costs(opts)
    TartarusDashboard.stop(dash)
    {agents, rate(opts, us) |> Map.put(:sample_costs_us, costs)}
  end

  defp condition(:page, net, agents, hosts, opts, browser) do
    Health.stop()
    {:ok, dash} = TartarusEmu.Dashboard.start_link(net, health: opts[:health])

    {agents, us, seen} =
      if browser do
        :ok = Browser.open(browser, TartarusDashboard.url(dash))
        :ok = Browser.wait(browser, "document.body.dataset.ready === '1'", 15_000)

        :ok =
          Browser.wait(browser, "document.getElementById('stream').textContent === 'live'", 5_000)

        {:ok, r0} = Browser.eval(browser, "S.received")
        {agents, us} = drive(agents, hosts, opts[:moves])
        Clock.machine_sleep(600)
        {:ok, r1} = Browser.eval(browser, "[S.received, S.batches]")
        :ok = Browser.open(browser, "about:blank")
        {agents, us, %{page_events: hd(r1) - r0, page_batches: List.last(r1)}}
      else
        sock = sse_connect(TartarusDashboard.port(dash))
        reader = spawn_link(fn -> sse_drain(sock, 0) end)
        {agents, us} = drive(agents, hosts, opts[:moves])
        Clock.machine_sleep(600)
        send(reader, {:done, self()})

        bytes =
          receive do
            {:sse_bytes, n} -> n
          end

        {agents, us, %{page_stream_bytes: bytes}}
      end

    {:ok, body} = get(TartarusDashboard.url(dash) <> "api/summary")
    feed = Tartarus.JSON.decode!(body)["feed"]
    costs = sampled_costs(opts)
    TartarusDashboard.stop(dash)

    {agents,
     rate(opts, us)
     |> Map.merge(seen)
     |> Map.merge(%{feed_dropped: feed["dropped"], sample_costs_us: costs})}
  end

  # What the health samples taken during a run cost (µs each), newest last.
  defp sampled_costs(opts) do
    if opts[:health], do: Enum.map(Health.series(300), & &1.cost_us), else: []
  end

  defp sample_cost(runs) do
    costs = Enum.flat_map(runs, &Map.get(&1, :sample_costs_us, []))

    case costs do
      [] ->
        nil

      _ ->
        %{
          samples: length(costs),
          median_us: TartarusTools.Stats.median(costs),
          max_us: Enum.max(costs)
        }
    end
  end

  defp rate(opts, us) do
    moves = opts[:agents] * opts[:moves]
    %{wall_ms: div(us, 1000), migrations_per_s: Float.round(moves * 1_000_000 / us, 1)}
  end

  # Every agent moves `moves` times to the next host of the ring, each by its own process.
  defp drive(agents, hosts, moves) do
    n = tuple_size(hosts)
    t0 = Clock.machine_time(:microsecond)

    agents =
      agents
      |> Enum.map(fn {id, at} ->
        Task.async(fn ->
          Enum.reduce(1..moves, at, fn _, at ->
            to = rem(at + 1, n)
            :ok = Tartarus.move({id, elem(hosts, at)}, elem(hosts, to))
            to
          end)
          |> then(&{id, &1})
        end)
      end)
      |> Task.await_many(:infinity)

    {agents, Clock.machine_time(:microsecond) - t0}
  end

  defp sse_connect(port) do
    {:ok, sock} = :gen_tcp.connect(~c"127.0.0.1", port, [:binary, active: false])
    :ok = :gen_tcp.send(sock, "GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1:#{port}\r\n\r\n")
    {:ok, _head} = :gen_tcp.recv(sock, 0, 5_000)
    sock
  end

  defp sse_drain(sock, n) do
    receive do
      {:done, from} ->
        :gen_tcp.close(sock)
        send(from, {:sse_bytes, n})
    after
      0 ->
        case :gen_tcp.recv(sock, 0, 50) do
          {:ok, data} -> sse_drain(sock, n + byte_size(data))
          {:error, :timeout} -> sse_drain(sock, n)
          {:error, _} -> sse_drain_closed(n)
        end
    end
  end

  defp sse_drain_closed(n) do
    receive do
      {:done, from} -> send(from, {:sse_bytes, n})
    end
  end

  # -- 2. 10,000 hosts -------------------------------------------------------------------

  defp big(opts) do
    rows = opts[:big_rows]
    cols = opts[:big_cols]
    hosts = rows * cols
    :ok = TartarusTools.Peer.ensure_distributed("dash_bench")
    name = :"dash_bench_big_#{System.unique_integer([:positive])}"
    procs = max(hosts * 6 + opts[:big_agents] * 2 + 100_000, 1_048_576)
    tables = max(hosts * 3 + 4_096, 16_384)
    args = ["+P", Integer.to_string(procs), "+e", Integer.to_string(tables)]

    {:ok, peer, node} =
      TartarusTools.Peer.start(name, args: args, apps: [:tartarus, :tartarus_emu])

    try do
      me = self()
      holder = Node.spawn(node, __MODULE__, :hold, [me, rows, cols, opts[:big_agents]])
      ref = Process.monitor(holder)

      MachineClock.receive do
        {:ready, info} -> measure_big(info, hosts, opts)
        {:DOWN, ^ref, _, _, reason} -> %{error: "the big network failed: #{inspect(reason)}"}
      after
        600_000 -> %{error: "the big network did not start in 10 minutes"}
      end
    after
      TartarusTools.Peer.stop(peer)
    end
  end

  @doc false
  # Runs on the big node: starts the grid, its agents and a dashboard, reports, keeps 100
  # agents moving, and lives until the node stops.
  def hold(from, rows, cols, n_agents) do
    t0 = Clock.machine_time(:millisecond)
    topo = Topology.grid(rows, cols)
    {:ok, net} = Network.start(topo)
    t1 = Clock.machine_time(:millisecond)
    nodes = topo.nodes
    count = length(nodes)
    step = max(div(count, n_agents), 1)

    agents =
      for i <- 0..(n_agents - 1) do
        n = Enum.at(nodes, rem(i * step, count))

        {:ok, id} =
          Tartarus.create_mobile_agent(Network.host(net, n), Tartarus.Examples.Echo, nil)

        {id, n}
      end

    {:ok, dash} = TartarusEmu.Dashboard.start_link(net)
    t2 = Clock.machine_time(:millisecond)

    send(
      from,
      {:ready, %{url: TartarusDashboard.url(dash), network_ms: t1 - t0, agents_ms: t2 - t1}}
    )

    walk(net, topo, Enum.take(agents, 100))
  end

  defp walk(net, topo, agents) do
    agents =
      Enum.map(agents, fn {id, at} ->
        to = topo |> Topology.neighbours(at) |> hd()

        case Tartarus.move({id, Network.host(net, at)}, Network.host(net, to)) do
          :ok -> {id, to}
          _ -> {id, at}
        end
      end)

    Clock.sleep(100)
    walk(net, topo, agents)
  end

  @big_paths [
    "/",
    "/api/info",
    "/api/summary",
    "/api/hosts",
    "/api/hosts?limit=10000",
    "/api/hosts?limit=50&sort=residents",
    "/api/links",
    "/api/agents",
    "/api/events"
  ]

  defp measure_big(info, hosts, _opts) do
    base = String.trim_trailing(info.url, "/")
    # The big node listens on 127.0.0.1 of this machine too.
    api =
      Map.new(@big_paths, fn path ->
        times =
          for _ <- 1..3 do
            t0 = Clock.machine_time(:microsecond)
            {:ok, body} = get(base <> path)
            {Clock.machine_time(:microsecond) - t0, byte_size(body)}
          end

        {path,
         %{
           bytes: elem(hd(times), 1),
           first_ms: Float.round(elem(hd(times), 0) / 1000, 1),
           then_ms: Enum.map(tl(times), &Float.round(elem(&1, 0) / 1000, 1))
         }}
      end)

    page =
      case Browser.executable() && Browser.start() do
        {:ok, b} ->
          try do
            t0 = Clock.machine_time(:millisecond)
            :ok = Browser.open(b, info.url)
            :ok = Browser.wait(b, "document.body.dataset.ready === '1'", 60_000)
            ready = Clock.machine_time(:millisecond) - t0
            Clock.machine_sleep(4_000)

            {:ok, seen} =
              Browser.eval(b, """
              ({aggregated: !!document.getElementById('aggregate'),
                overlay_drawn: !!document.getElementById('overlay'),
                groups: document.querySelectorAll('#aggregate rect.bucket').length,
                host_rows: document.querySelectorAll('#hosts tbody tr').length,
                agent_rows: document.querySelectorAll('#agents tbody tr').length,
                title: document.getElementById('graph-title').textContent,
                events_received: S.received, batches: S.batches,
                js_heap_mb: performance.memory ? Math.round(performance.memory.usedJSHeapSize / 1e6) : null})
              """)

            Map.put(seen, "ready_ms", ready)
          after
            Browser.stop(b)
          end

        _ ->
          %{skipped: "no chromium"}
      end

    %{hosts: hosts, network_ms: info.network_ms, agents_ms: info.agents_ms, api: api, page: page}
  end

  defp get(url) do
    case TartarusDashboard.http_get(url, 120_000) do
      {:ok, 200, body} -> {:ok, body}
      other -> {:error, other}
    end
  end
end
