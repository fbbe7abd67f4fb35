defmodule TartarusEmu.Network do
  @moduledoc """
  Emulated networks: a topology brought to life as Tartarus hosts, with links that break and
  heal, nodes that break off and rejoin, and (in peer mode) BEAM nodes that are killed and
  restarted.

  ## Glossary

    * **topology node** - a node of a `TartarusEmu.Topology` (`:h1`, `"lobby"`, ...).
    * **host** - the Tartarus host standing for a topology node, addressed `{name, node}`
      (`host/2` translates).
    * **BEAM node** - an Erlang node. In `:virtual` mode every host lives in this VM; in
      `:peer` mode each group of `:group` consecutive topology nodes gets its own BEAM node,
      started with `:peer` (`TartarusTools.Peer`), `-connect_all false`.
    * **origin** - the node that called `start/2`. It is connected to every peer (that is how
      it controls them); peers are connected only to the nodes of their overlay neighbours.
    * **live link** - a topology edge that is not broken and whose two ends are neither
      isolated nor on a killed BEAM node. Exactly the live links are overlay links of the
      hosts (`Tartarus.neighbours/1`).

  ## Example

      {:ok, net} = TartarusEmu.Network.start(TartarusEmu.Topology.grid(3, 3))
      :ok = TartarusEmu.Network.break_link(net, :h1, :h2)
      Tartarus.neighbours(TartarusEmu.Network.host(net, :h1))   # only h4's host now
      :ok = TartarusEmu.Network.heal_link(net, :h1, :h2)
      :ok = TartarusEmu.Network.stop(net)

  ## What "break" means

  Hosts are started with `strict_links: true`, so an agent can migrate only along an overlay
  link. Breaking a link removes it from both hosts' neighbour sets (`Tartarus.disconnect/2`):
  moves over it fail with `{:no_link, host}` and strategies no longer pick it. Its latency and
  loss are kept by the topology and come back on `heal_link/3`. In peer mode the BEAM
  connection between the two hosts' nodes is also dropped when no other live link joins
  them (with `group: 1`, always). It is not a firewall: distributed Erlang connects again on
  the next message between the two nodes, and a message that follows a forwarding pointer
  (a `Tartarus.request/3` to an agent that moved) may do so; agent migration never does,
  because it follows live links only. `heal_link/3` reconnects the nodes explicitly. The
  origin's own connections are never touched (hosts on one node talk through the origin
  only when the origin drives them: `Tartarus.connect/3`, `Tartarus.post/3`, ...).

  ## Isolation (the thesis's node breaking off)

  `isolate/2` takes every link of a node down (the node is "off the network"); `rejoin/2`
  brings back those of its links that are live again. `TartarusEmu.Dynamics` decides which
  nodes break off and reconnect each tick; `apply_dynamics/2` carries its events out.

  ## Kill and restart

  `kill_node/2` stops a host with its agents: in peer mode the whole BEAM node of the
  topology node's group goes down (every host of the group), in virtual mode only that
  host. Its neighbours keep their links to it (they learn of the failure when a move fails,
  as on a real network; `isolate/2` first to take the links down too). `restart_node/2`
  starts the host(s) again **empty**: agents that were on them are lost (persistence is a
  separate feature of the platform), the links that are live are connected again, and the
  setup hook (below) runs again on the restarted nodes.

  ## Per-node setup (how an application plugs in)

  `start/2` takes `setup: fn topo_node, host -> ... end`, called for every topology node
  once all hosts are linked: the application attaches its plugins and creates its static
  agents there. The same hook serves both modes (it runs on the origin and reaches each
  host through the platform), so an application never starts or links hosts itself:

      setup = fn n, host ->
        Tartarus.attach_plugin(host, :sensor, {Tartarus.Plugin.SimSensor, signal: [1, 2]})
        Tartarus.create_static_agent(host, MyApp.Counter, %{node: n}, name: "counter")
      end

      {:ok, net} = TartarusEmu.Network.start(TartarusEmu.Topology.ring(8), setup: setup)

  `TartarusEmu.Scenario` drives such a network step by step; `docs/emulator.md` ("How an
  application plugs in") walks through a complete example.

  ## Cleanup

  A keeper process owns the network's bookkeeping and its peer nodes and watches the caller
  of `start/2`: if the caller dies, the hosts and peers go with it. `stop/1` stops everything.
  """

  alias TartarusEmu.Network.Keeper
  alias TartarusEmu.Topology

  @enforce_keys [:topology, :mode, :hosts, :nodes, :keeper]
  defstruct [
    :topology,
    :mode,
    :hosts,
    :nodes,
    :keeper,
    :table,
    setup: nil,
    host_opts: [],
    node_opts: %{},
    group: 1,
    peers: [],
    adjacency: %{},
    index: %{}
  ]

  @typedoc "How hosts are placed: all in this VM, or on `:peer` BEAM nodes."
  @type mode :: :virtual | :peer

  @typedoc """
  A running network: its topology, mode, `hosts` (topology node => host address), the BEAM
  `nodes` it uses (in peer mode one per group, in group order), the peer owners, the keeper.
  """
  @type t :: %__MODULE__{
          topology: Topology.t(),
          mode: mode(),
          hosts: %{optional(Topology.name()) => Tartarus.host()},
          nodes: [node()],
          keeper: pid(),
          table: :ets.tid() | nil,
          group: pos_integer(),
          peers: [pid()],
          adjacency: %{optional(Topology.name()) => [Topology.name()]},
          index: %{optional(Tartarus.host()) => Topology.name()},
          setup: setup() | nil,
          host_opts: keyword(),
          node_opts: %{optional(Topology.name()) => keyword()}
        }

  @typedoc """
  A per-node setup hook: called as `setup.(topo_node, host)` (or, for a 3-ary function,
  `setup.(topo_node, host, network)`, when the node needs to know the others, e.g. its
  neighbours' hosts) for every topology node once the hosts are up and linked (and again for the nodes of a restarted BEAM node or host).
  It attaches plugins, creates static agents, fills the host store: whatever the
  application needs on every node. It returns `:ok` or `{:ok, _}`; anything else stops
  `start/2` with `{:error, {:setup_failed, topo_node, returned}}`.

  The hook runs in the caller's process (on the origin) in both modes and reaches the host
  through the platform (`Tartarus.attach_plugin/3`, `Tartarus.create_static_agent/4`, ...),
  which work the same on a local and a remote host, so one hook serves virtual and peer
  mode alike.
  """
  @type setup ::
          (Topology.name(), Tartarus.host() -> :ok | {:ok, term()} | term())
          | (Topology.name(), Tartarus.host(), t() -> :ok | {:ok, term()} | term())

  @schema [
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    group: [type: :pos_integer, default: 1, doc: "topology nodes per BEAM node (peer mode)"],
    host_opts: [type: :keyword, default: [], doc: "extra options of `Tartarus.start_host/2`"],
    node_opts: [
      type: :map,
      default: %{},
      doc:
        "per topology node, more options of `Tartarus.start_host/2` merged over `:host_opts` (e.g. `%{\"jd\" => [data_dir: dir]}`: persistence for one host); a restarted node gets them again"
    ],
    prefix: [
      type: :any,
      default: "emu",
      doc:
        "host names are `\"<prefix><tag>-<node>\"` (strings, `<tag>` unique per network); `nil` keeps the topology names"
    ],
    peer_args: [type: {:list, :string}, default: [], doc: "extra `erl` arguments of peers"],
    max_processes: [type: :pos_integer, default: 32_768, doc: "`+P` of each peer node"],
    concurrency: [type: :pos_integer, default: 6, doc: "peers started at once"],
    link: [type: :keyword, default: [], doc: "default `:latency_ms`/`:loss` of every link"],
    setup: [
      type: :any,
      doc:
        "per-node setup hook `fn topo_node, host -> :ok end` (or `fn topo_node, host, net -> ... end`), run in topology order after linking (see `t:setup/0`)"
    ]
  ]

  @doc """
  Starts a host per topology node and links them along the topology's edges (with each
  edge's latency and loss). Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, network}` or `{:error, reason}` (nothing is left running on error).
  Hosts are linked in sorted edge order, so neighbour lists (and thus agents' random
  choices) are the same on every run.
  """
  @spec start(Topology.t(), keyword()) :: {:ok, t()} | {:error, term()}
  def start(%Topology{} = topo, opts \\ []) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusEmu.Network.start/2"),
         :ok <- check_prefix(opts[:prefix]),
         :ok <- check_setup(opts[:setup]),
         {:ok, link_defaults} <-
           Tartarus.Options.validate(
             opts[:link],
             [latency_ms: [type: :non_neg_integer], loss: [type: :probability]],
             "TartarusEmu.Network.start/2 (:link)"
           ) do
      # Fixed width (6 base-36 digits, unique for 2 billion networks per VM), so that host
      # names, and the bytes of envelopes that carry them, have the same size on every run;
      # the n-th network of this VM (a counter, not System.unique_integer/1, whose value
      # depends on the scheduler that asks), so that its host names are the same on every
      # run: the order of maps keyed by them, and so every choice made by walking one, too.
      tag =
        :persistent_term.get({__MODULE__, :tags})
        |> :atomics.add_get(1, 1)
        |> rem(2_176_782_336)
        |> Integer.to_string(36)
        |> String.pad_leading(6, "0")

      names = Map.new(topo.nodes, &{&1, host_name(opts[:prefix], tag, &1)})
      {:ok, keeper, table} = Keeper.start(self())

      net = %__MODULE__{
        topology: %{topo | links: default_links(topo, link_defaults)},
        mode: opts[:mode],
        hosts: %{},
        nodes: [],
        keeper: keeper,
        table: table,
        setup: opts[:setup],
        group: opts[:group],
        adjacency: Topology.adjacency(topo)
      }

      host_opts = Keyword.put(opts[:host_opts], :strict_links, true)
      net = %{net | host_opts: host_opts, node_opts: opts[:node_opts]}

      result =
        case opts[:mode] do
          :virtual -> start_virtual(net, names, host_opts)
          :peer -> start_peers(net, names, host_opts, opts, tag)
        end

      with {:ok, net} <- result,
           net = %{net | index: Map.new(net.hosts, fn {n, h} -> {h, n} end)},
           :ok <- connect_edges(net),
           :ok <- run_setup(net, net.topology.nodes) do
        {:ok, net}
      else
        error ->
          Keeper.stop(keeper)
          error
      end
    end
  end

  defp check_setup(nil), do: :ok
  defp check_setup(f) when is_function(f, 2) or is_function(f, 3), do: :ok

  defp check_setup(f),
    do:
      {:error,
       "invalid options given to TartarusEmu.Network.start/2 for key :setup: expected a function of 2 or 3 arguments, got: #{inspect(f)}"}

  defp check_prefix(nil), do: :ok
  defp check_prefix(p) when is_binary(p), do: :ok

  defp check_prefix(p),
    do:
      {:error,
       "invalid options given to TartarusEmu.Network.start/2 for key :prefix: expected a string or nil, got: #{inspect(p)}"}

  defp host_name(nil, _tag, node), do: node
  defp host_name(prefix, tag, node), do: "#{prefix}#{tag}-#{node}"

  defp default_links(topo, []), do: topo.links

  defp default_links(topo, defaults) do
    Map.new(topo.edges, fn edge ->
      {edge, Map.merge(Map.new(defaults), topo.links[edge] || %{})}
    end)
  end

  defp start_virtual(net, names, host_opts) do
    Keeper.track_hosts(net.keeper, Map.values(names))

    net.topology.nodes
    |> Task.async_stream(
      fn n -> {n, Tartarus.start_host(Map.fetch!(names, n), host_opts_of(net, n, host_opts))} end,
      max_concurrency: System.schedulers_online() * 2,
      timeout: :infinity
    )
    |> Enum.reduce_while({:ok, %{}}, fn
      {:ok, {n, {:ok, host}}}, {:ok, acc} -> {:cont, {:ok, Map.put(acc, n, host)}}
      {:ok, {n, error}}, _ -> {:halt, {:error, {:host_failed, n, error}}}
    end)
    |> case do
      {:ok, hosts} -> {:ok, %{net | hosts: hosts, nodes: [node()]}}
      error -> error
    end
  end

  defp start_peers(net, names, host_opts, opts, tag) do
    groups = Enum.chunk_every(net.topology.nodes, net.group)
    peer_args = ["+S", "1:1", "+P", Integer.to_string(opts[:max_processes])] ++ opts[:peer_args]

    specs =
      groups
      |> Enum.with_index(1)
      |> Enum.map(fn {members, i} ->
        %{
          name: :"#{opts[:prefix] || "emu"}#{String.downcase(tag)}_#{i}",
          args: peer_args,
          hosts: Enum.map(members, &{&1, Map.fetch!(names, &1)}),
          host_opts: host_opts,
          node_opts: Map.take(net.node_opts, members)
        }
      end)

    case Keeper.start_peers(net.keeper, specs, opts[:concurrency]) do
      {:ok, started} ->
        hosts =
          for {spec, {_owner, node}} <- Enum.zip(specs, started),
              {n, name} <- spec.hosts,
              into: %{},
              do: {n, {name, node}}

        {:ok,
         %{
           net
           | hosts: hosts,
             nodes: Enum.map(started, &elem(&1, 1)),
             peers: Enum.map(started, &elem(&1, 0))
         }}

      error ->
        error
    end
  end

  defp connect_edges(net) do
    net.topology.edges
    |> Enum.sort()
    |> Enum.reduce_while(:ok, fn {a, b}, :ok ->
      case connect(net, a, b) do
        :ok -> {:cont, :ok}
        error -> {:halt, {:error, {:link_failed, {a, b}, error}}}
      end
    end)
  end

  defp run_setup(%{setup: nil}, _nodes), do: :ok

  defp run_setup(%{setup: setup} = net, nodes) do
    Enum.reduce_while(nodes, :ok, fn n, :ok ->
      result =
        if is_function(setup, 3), do: setup.(n, host(net, n), net), else: setup.(n, host(net, n))

      case result do
        :ok -> {:cont, :ok}
        {:ok, _} -> {:cont, :ok}
        other -> {:halt, {:error, {:setup_failed, n, other}}}
      end
    end)
  end

  @doc "Stops every host and peer node of the network. Returns `:ok`."
  @spec stop(t()) :: :ok
  def stop(%__MODULE__{keeper: keeper}), do: Keeper.stop(keeper)

  @doc """
  The host address of a topology node.

      iex> {:ok, net} = TartarusEmu.Network.start(TartarusEmu.Topology.line(2), prefix: nil)
      iex> TartarusEmu.Network.host(net, :h2)
      {:h2, node()}
      iex> TartarusEmu.Network.stop(net)
      :ok
  """
  @spec host(t(), Topology.name()) :: Tartarus.host()
  def host(%__MODULE__{hosts: hosts}, topo_node), do: Map.fetch!(hosts, topo_node)

  @doc "The topology node a host address stands for (`nil` if none)."
  @spec topo_node(t(), Tartarus.host()) :: Topology.name() | nil
  def topo_node(%__MODULE__{index: index}, host), do: Map.get(index, host)

  @doc "The BEAM node a topology node's host runs on."
  @spec beam_node(t(), Topology.name()) :: node()
  def beam_node(net, topo_node), do: elem(host(net, topo_node), 1)

  # -- links ---------------------------------------------------------------------

  @doc """
  Breaks the link between topology nodes `a` and `b` (see "What break means"). Breaking a
  broken link is fine. Returns `{:error, {:no_such_link, a, b}}` for a non-edge.
  """
  @spec break_link(t(), Topology.name(), Topology.name()) :: :ok | {:error, term()}
  def break_link(net, a, b) do
    with {:ok, edge} <- edge(net, a, b) do
      Keeper.put(net, {:broken, edge})
      disconnect(net, a, b)
    end
  end

  @doc """
  Heals the link between `a` and `b`: it is an overlay link again (same latency and loss)
  unless one end is isolated or killed, in which case it comes back with that end.
  """
  @spec heal_link(t(), Topology.name(), Topology.name()) :: :ok | {:error, term()}
  def heal_link(net, a, b) do
    with {:ok, edge} <- edge(net, a, b) do
      Keeper.delete(net, {:broken, edge})
      if live?(net, a, b), do: connect(net, a, b), else: :ok
    end
  end

  @doc "Takes every link of topology node `n` down (the thesis's node breaking off)."
  @spec isolate(t(), Topology.name()) :: :ok
  def isolate(net, n) do
    Keeper.put(net, {:isolated, n})
    Enum.each(neighbours(net, n), &disconnect(net, n, &1))
  end

  @doc "Ends the isolation of `n`: its links that are live again come back."
  @spec rejoin(t(), Topology.name()) :: :ok
  def rejoin(net, n) do
    Keeper.delete(net, {:isolated, n})
    Enum.each(neighbours(net, n), fn m -> if live?(net, n, m), do: connect(net, n, m) end)
  end

  @doc """
  Carries out the events of a `TartarusEmu.Dynamics` tick over topology nodes
  (`{:down, n}` isolates `n`, `{:up, n}` rejoins it), in order.
  """
  @spec apply_dynamics(t(), [TartarusEmu.Dynamics.event()]) :: :ok
  def apply_dynamics(net, events) do
    Enum.each(events, fn
      {:down, n} -> isolate(net, n)
      {:up, n} -> rejoin(net, n)
    end)
  end

  @doc "True if the edge `a`-`b` exists and is live (see the glossary)."
  @spec live?(t(), Topology.name(), Topology.name()) :: boolean()
  def live?(net, a, b) do
    case edge(net, a, b) do
      {:ok, edge} ->
        not Keeper.member?(net, {:broken, edge}) and up?(net, a) and up?(net, b)

      _ ->
        false
    end
  end

  @doc "The live edges, sorted."
  @spec live_links(t()) :: [Topology.edge()]
  def live_links(net) do
    net.topology.edges |> Enum.filter(fn {a, b} -> live?(net, a, b) end) |> Enum.sort()
  end

  @doc "True unless `n` is isolated or its host is killed."
  @spec up?(t(), Topology.name()) :: boolean()
  def up?(net, n) do
    not Keeper.member?(net, {:isolated, n}) and not killed?(net, n)
  end

  @doc "The topology nodes currently isolated, sorted."
  @spec isolated(t()) :: [Topology.name()]
  def isolated(net), do: net |> Keeper.keys(:isolated) |> Enum.sort()

  defp killed?(%{mode: :peer} = net, n), do: Keeper.member?(net, {:killed, beam_node(net, n)})
  defp killed?(net, n), do: Keeper.member?(net, {:killed, n})

  defp neighbours(net, n), do: Map.get(net.adjacency, n, [])

  defp edge(net, a, b) do
    edge = if a < b, do: {a, b}, else: {b, a}

    if MapSet.member?(net.topology.edges, edge),
      do: {:ok, edge},
      else: {:error, {:no_such_link, a, b}}
  end

  defp connect(net, a, b) do
    {:ok, props} = Topology.fetch_link(net.topology, a, b)
    ha = host(net, a)
    hb = host(net, b)
    props = [latency_ms: round(props.latency_ms), loss: props.loss]

    if TartarusEmu.Links.emulated?(props),
      do: TartarusEmu.Links.install([elem(ha, 1), elem(hb, 1)])

    with :ok <- Tartarus.connect(ha, hb, props) do
      connect_nodes(elem(ha, 1), elem(hb, 1))
    end
  end

  defp disconnect(net, a, b) do
    ha = host(net, a)
    hb = host(net, b)
    # Either end may be down (killed): removing the link on the live end is what matters.
    _ = Tartarus.disconnect(ha, hb)
    {na, nb} = {elem(ha, 1), elem(hb, 1)}

    if na != nb and not nodes_linked?(net, na, nb) do
      try do
        :erpc.call(na, :erlang, :disconnect_node, [nb], 10_000)
      catch
        _, _ -> :ok
      end
    end

    :ok
  end

  defp connect_nodes(same, same), do: :ok

  defp connect_nodes(na, nb) do
    case :erpc.call(na, :net_kernel, :connect_node, [nb], 15_000) do
      true -> :ok
      other -> {:error, {:node_connect_failed, na, nb, other}}
    end
  catch
    _, reason -> {:error, {:node_connect_failed, na, nb, reason}}
  end

  # Is there a live link between any host of node `na` and any host of node `nb`?
  defp nodes_linked?(net, na, nb) do
    Enum.any?(net.topology.edges, fn {a, b} ->
      ends = {beam_node(net, a), beam_node(net, b)}
      (ends == {na, nb} or ends == {nb, na}) and live?(net, a, b)
    end)
  end

  # -- kill and restart -------------------------------------------------------------

  @doc """
  Kills topology node `n`: in peer mode the BEAM node of its group (all hosts of the group),
  in virtual mode its host. Agents on it are lost. See "Kill and restart".
  """
  @spec kill_node(t(), Topology.name()) :: :ok | {:error, term()}
  def kill_node(%{mode: :peer} = net, n) do
    node = beam_node(net, n)
    Keeper.put(net, {:killed, node})
    Keeper.kill_peer(net.keeper, node)
  end

  def kill_node(net, n) do
    Keeper.put(net, {:killed, n})
    _ = Tartarus.stop_host(host(net, n))
    :ok
  end

  @doc """
  Restarts a killed topology node (in peer mode its whole group's BEAM node, under the same
  node name) with empty hosts, and connects its live links again.
  """
  @spec restart_node(t(), Topology.name()) :: :ok | {:error, term()}
  def restart_node(%{mode: :peer} = net, n) do
    node = beam_node(net, n)
    members = for {m, {_, ^node}} <- net.hosts, do: m

    with :ok <- Keeper.restart_peer(net.keeper, node) do
      Keeper.delete(net, {:killed, node})
      reconnect(net, members)
      run_setup(net, Enum.filter(net.topology.nodes, &(&1 in members)))
    end
  end

  def restart_node(net, n) do
    {name, _} = host(net, n)

    with {:ok, _} <- Tartarus.start_host(name, host_opts_of(net, n, net.host_opts)) do
      Keeper.delete(net, {:killed, n})
      reconnect(net, [n])
      run_setup(net, [n])
    end
  end

  # The start options of topology node `n`'s host.
  defp host_opts_of(net, n, host_opts) do
    host_opts = if host_opts == [], do: [strict_links: true], else: host_opts
    Keyword.merge(host_opts, Map.get(net.node_opts, n, []))
  end

  defp reconnect(net, members) do
    members
    |> Enum.flat_map(fn m -> Enum.map(neighbours(net, m), &{m, &1}) end)
    |> Enum.sort()
    |> Enum.each(fn {a, b} -> if live?(net, a, b), do: connect(net, a, b) end)
  end

  # -- agents --------------------------------------------------------------------------

  @doc """
  Sends `message` as a plain Erlang message to every agent resident on the network's hosts
  (it arrives in the agent's `handle_info/2`). Returns how many agents it reached.

  The resident agents of every host are listed first (one remote call per BEAM node), then
  the messages are sent, so an agent that moves on receiving the message is not reached a
  second time at its new host. Cheap enough for 100,000 agents. Agents in the middle of a
  migration are not reached (their paused copy drops plain messages).
  """
  @spec broadcast(t(), term()) :: non_neg_integer()
  def broadcast(net, message) do
    net
    |> resident_pids()
    |> Enum.reduce(0, fn pids, acc ->
      Enum.each(pids, &send(&1, message))
      acc + length(pids)
    end)
  end

  @doc "The pids of the agents resident on the network's hosts now, as a list per host."
  @spec resident_pids(t()) :: [[pid()]]
  def resident_pids(net) do
    net
    |> hosts_by_node()
    |> Task.async_stream(
      fn {node, names} ->
        if node == node() do
          local_pids(names)
        else
          try do
            :erpc.call(node, __MODULE__, :local_pids, [names], 60_000)
          catch
            _, _ -> []
          end
        end
      end,
      max_concurrency: 16,
      timeout: :infinity,
      ordered: false
    )
    |> Enum.flat_map(fn {:ok, lists} -> lists end)
  end

  @doc false
  # Runs on the hosts' node.
  def local_pids(names) do
    Enum.map(names, fn name ->
      case Tartarus.agents({name, node()}) do
        list when is_list(list) -> Enum.map(list, & &1.pid)
        _ -> []
      end
    end)
  end

  @doc "The network's hosts grouped by BEAM node: `[{node, [host_name]}]`, live nodes only."
  @spec hosts_by_node(t()) :: [{node(), [Tartarus.host_name()]}]
  def hosts_by_node(net) do
    net.hosts
    |> Enum.reject(fn {n, _} -> killed?(net, n) end)
    |> Enum.group_by(fn {_, {_, node}} -> node end, fn {_, {name, _}} -> name end)
    |> Enum.sort()
  end

  @doc "Every host address of the network, in topology order."
  @spec host_list(t()) :: [Tartarus.host()]
  def host_list(net), do: Enum.map(net.topology.nodes, &host(net, &1))
end
