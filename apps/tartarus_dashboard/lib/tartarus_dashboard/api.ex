defmodule TartarusDashboard.Api do
  @moduledoc false
  # The JSON HTTP API (documented in docs/dashboard.md): a request map in
  # (%{method, path, query, headers, body}), {status, content_type, body} or :stream out;
  # admit/2 runs first, on the line and headers alone.
  # Reads need nothing; every POST needs the token. Nothing here makes an atom from input:
  # hosts, agents, modules and panels are looked up among those that exist.

  alias TartarusDashboard.{Feed, Fleet, Health, Page, Panel, Processes, Term}
  alias Tartarus.Clock
  alias Tartarus.JSON

  @cache_ms 1_000
  @id ~r/\A[0-9a-f]{16}\z/

  # What needs only the request line and the headers, checked before the body is read
  # (TartarusDashboard.Http.Conn): an action (a POST on a known endpoint) needs the
  # token. :ok, or the answer. (The body's size limit is the HTTP layer's.)
  def admit(%{method: "POST"} = req, ctx) do
    segs = String.split(req.path, "/", trim: true)

    with true <- known_post?(segs),
         {:error, status, code, message} <- authorize(req, ctx) do
      error(status, code, message)
    else
      _ -> :ok
    end
  end

  def admit(_req, _ctx), do: :ok

  def handle(req, ctx) do
    segs = String.split(req.path, "/", trim: true)
    route(req.method, segs, req, ctx)
  end

  # -- routes ---------------------------------------------------------------------------

  defp route("GET", [], _req, _ctx), do: {200, "text/html; charset=utf-8", Page.html()}
  defp route("GET", ["favicon.ico"], _req, _ctx), do: {204, "image/x-icon", ""}
  defp route("GET", ["api"], _req, _ctx), do: json(200, %{endpoints: endpoints()})
  defp route("GET", ["api", "stream"], _req, _ctx), do: :stream
  defp route("GET", ["api", "info"], _req, ctx), do: json(200, info(ctx))
  defp route("GET", ["api", "hosts"], req, ctx), do: with_query(req, &hosts(&1, ctx))
  defp route("GET", ["api", "hosts", id], _req, ctx), do: host_detail(id, ctx)
  defp route("GET", ["api", "links"], req, ctx), do: with_query(req, &links(&1, ctx))
  defp route("GET", ["api", "summary"], _req, ctx), do: json(200, summary(ctx))
  defp route("GET", ["api", "agents"], req, ctx), do: with_query(req, &agents(&1, ctx))
  defp route("GET", ["api", "agents", id], req, ctx), do: agent_detail(id, req, ctx)
  defp route("GET", ["api", "events"], req, ctx), do: with_query(req, &events(&1, ctx))
  defp route("GET", ["api", "catalog"], _req, ctx), do: json(200, %{catalog: catalog(ctx)})
  defp route("GET", ["api", "panels"], _req, ctx), do: json(200, %{panels: panels(ctx)})
  defp route("GET", ["api", "fleet"], _req, ctx), do: json(200, fleet(ctx))
  defp route("GET", ["api", "health"], req, ctx), do: with_query(req, &health(&1, ctx))
  defp route("GET", ["api", "rates"], req, ctx), do: with_query(req, &rates(&1, ctx))
  defp route("GET", ["api", "processes"], req, ctx), do: with_query(req, &processes(&1, ctx))

  defp route("POST", ["api" | rest] = segs, req, ctx) do
    if known_post?(segs) do
      with :ok <- authorize(req, ctx),
           {:ok, params} <- params(req) do
        action(rest, params, ctx)
      else
        {:error, status, code, message} -> error(status, code, message)
      end
    else
      other_method("POST", segs, req)
    end
  end

  defp route(method, segs, req, _ctx), do: other_method(method, segs, req)

  defp other_method(method, segs, req) do
    if Enum.any?(["GET", "POST"], &(&1 != method and match?({:ok, _}, routable(&1, segs)))),
      do: error(405, "method_not_allowed", "#{method} is not allowed on #{req.path}"),
      else: not_found(req)
  end

  defp not_found(req), do: error(404, "not_found", "no such endpoint: #{req.method} #{req.path}")

  defp routable("GET", ["api", x])
       when x in ~w(info hosts links summary agents events catalog panels stream fleet health rates processes),
       do: {:ok, x}

  defp routable("GET", ["api", x, _]) when x in ~w(hosts agents), do: {:ok, x}
  defp routable("GET", []), do: {:ok, :page}
  defp routable("POST", segs), do: if(known_post?(segs), do: {:ok, :post}, else: :error)
  defp routable(_, _), do: :error

  defp known_post?(["api", "agents"]), do: true
  defp known_post?(["api", "token"]), do: true

  defp known_post?(["api", "agents", _, a]) when a in ~w(move clone kill post request),
    do: true

  defp known_post?(["api", "links", a]) when a in ~w(break heal), do: true
  defp known_post?(["api", "hosts", _, a]) when a in ~w(isolate rejoin), do: true
  defp known_post?(["api", "panels", _, _]), do: true
  defp known_post?(_), do: false

  defp endpoints do
    [
      "GET /api/info",
      "GET /api/hosts?offset=0&limit=1000&sort=residents",
      "GET /api/hosts/ID",
      "GET /api/links?limit=5000",
      "GET /api/summary",
      "GET /api/agents?host=ID&limit=5000",
      "GET /api/agents/ID",
      "GET /api/events?type=arrival&host=ID&agent=ID&since=SEQ&limit=200",
      "GET /api/stream (text/event-stream)",
      "GET /api/catalog",
      "GET /api/panels",
      "GET /api/fleet",
      "GET /api/health?node=NODE&host=ID&points=300",
      "GET /api/rates?seconds=120",
      "GET /api/processes?node=NODE&sort=memory|reductions|mailbox&limit=20",
      "POST /api/token (answers 200 when the token is right)",
      "POST /api/agents {host, module, args?, static?}",
      "POST /api/agents/ID/move {to}",
      "POST /api/agents/ID/clone {to}",
      "POST /api/agents/ID/kill",
      "POST /api/agents/ID/post {message} or {term}",
      "POST /api/agents/ID/request {term, timeout_ms?}",
      "POST /api/links/break {a, b}",
      "POST /api/links/heal {a, b}",
      "POST /api/hosts/ID/isolate",
      "POST /api/hosts/ID/rejoin",
      "POST /api/panels/NAME/ACTION {params}"
    ]
  end

  # -- reads ----------------------------------------------------------------------------

  defp info(ctx) do
    %{
      node: to_string(node()),
      emulation: ctx.emulation != nil,
      hosts: length(topology(ctx).hosts),
      catalog: catalog(ctx),
      panels: Enum.map(ctx.panels, fn {m, a} -> m.name(a) end),
      fleet: ctx.fleet != nil or length(shown_nodes(ctx)) > 1,
      kept: frozen?(ctx),
      token_required_for: "POST",
      max_body: ctx.max_body
    }
  end

  defp hosts(q, ctx) do
    with {:ok, offset} <- int(q, "offset", 0, 0, 10_000_000),
         {:ok, limit} <- int(q, "limit", 1_000, 1, 100_000),
         {:ok, sort} <- choice(q, "sort", ~w(topology residents arrivals refused bytes)) do
      all = host_views(ctx)

      sorted =
        case sort do
          "topology" -> all
          key -> Enum.sort_by(all, &(-Map.get(&1, String.to_existing_atom(key), 0)))
        end

      json(200, %{
        total: length(all),
        offset: offset,
        hosts: sorted |> Enum.drop(offset) |> Enum.take(limit)
      })
    end
  end

  defp links(q, ctx) do
    with {:ok, limit} <- int(q, "limit", 5_000, 1, 1_000_000) do
      all = topology(ctx).links
      json(200, %{total: length(all), links: Enum.take(all, limit)})
    end
  end

  defp host_detail(id, ctx) do
    with {:ok, h} <- find_host(id, ctx) do
      view = Enum.find(host_views(ctx), &(&1.id == id)) || host_view(h)
      agents = collect_agents([h])

      hop =
        case Map.get(h, :remote) do
          %{} = r ->
            %{median_us: r.hop_median_us, p99_us: r.hop_p99_us}

          nil ->
            case Tartarus.hop_stats(h.host) do
              m when is_map(m) -> m
              _ -> %{}
            end
        end

      json(200, Map.merge(view, %{agents: agents, hop: hop}))
    end
  end

  defp summary(ctx) do
    stats = Feed.stats(ctx.feed)

    ctx
    |> summary_views()
    |> Map.merge(%{
      totals:
        Map.take(Tartarus.Events.totals(), [
          :created,
          :arrivals,
          :departures,
          :refused,
          :bytes,
          :messages,
          :move_failed,
          :kills,
          :crashes
        ]),
      hop: stats.hop,
      feed: Map.take(stats, [:seq, :dropped, :clients]),
      counts: stats.counts
    })
  end

  # The summary's parts drawn from every host's view, cached as the views are: a page of
  # 10,000 hosts asks every few seconds, and reading the views out of the cache costs more
  # than this small result.
  defp summary_views(ctx) do
    cached(ctx, :summary, fn ->
      views = host_views(ctx)
      topo = topology(ctx)

      by_node =
        views
        |> Enum.group_by(& &1.node)
        |> Enum.map(fn {node, vs} -> Map.put(sum(vs), :node, node) end)
        |> Enum.sort_by(& &1.node)

      n = length(views)
      per = max(1, div(n + 99, 100))

      buckets =
        views
        |> Enum.chunk_every(per)
        |> Enum.map(fn vs ->
          Map.merge(sum(vs), %{first: hd(vs).id, last: List.last(vs).id})
        end)

      %{
        hosts: n,
        hosts_down: Enum.count(views, &(!&1.up)),
        links: length(topo.links),
        links_down: Enum.count(topo.links, &(!&1.up)),
        by_node: by_node,
        buckets: buckets,
        top: views |> Enum.sort_by(&(-&1.residents)) |> Enum.take(20)
      }
    end)
  end

  defp sum(vs) do
    Enum.reduce(
      vs,
      %{hosts: 0, down: 0, residents: 0, arrivals: 0, refused: 0, bytes: 0},
      fn v, acc ->
        %{
          hosts: acc.hosts + 1,
          down: acc.down + if(v.up, do: 0, else: 1),
          residents: acc.residents + v.residents,
          arrivals: acc.arrivals + v.arrivals,
          refused: acc.refused + v.refused,
          bytes: acc.bytes + v.bytes
        }
      end
    )
  end

  defp agents(q, ctx) do
    with {:ok, limit} <- int(q, "limit", 5_000, 1, 1_000_000),
         {:ok, hosts} <- host_filter(q, ctx) do
      all =
        case hosts do
          :all -> cached(ctx, :agents, fn -> collect_agents(topology(ctx).hosts) end)
          list -> collect_agents(list)
        end

      json(200, %{total: length(all), agents: Enum.take(all, limit)})
    end
  end

  defp host_filter(q, ctx) do
    case q["host"] do
      nil -> {:ok, :all}
      id -> with {:ok, h} <- find_host(id, ctx), do: {:ok, [h]}
    end
  end

  defp collect_agents(hosts) do
    # This node's agents in one read of its agent table (not a scan of every host's ledger).
    here = Enum.group_by(Tartarus.agents(), & &1.host)

    Enum.flat_map(hosts, fn
      %{remote: %{}} = h ->
        remote_agents(h)

      %{host: {_, n}} = h when n == node() ->
        if h.up,
          do:
            here
            |> Map.get(h.host, [])
            |> Enum.sort_by(& &1.name)
            |> Enum.map(&agent_view(&1, h.id, n)),
          else: []

      h ->
        local_agents(h)
    end)
  end

  # A remote host's agents, from its node's snapshot (no call to that node).
  defp remote_agents(%{host: {_name, node}} = h),
    do: Enum.map(h.agents, &agent_view(&1, h.id, node))

  defp local_agents(h) do
    case h.up && Tartarus.agents(h.host) do
      list when is_list(list) -> Enum.map(list, &agent_view(&1, h.id, elem(h.host, 1)))
      _ -> []
    end
  end

  defp agent_view(a, host_id, node) do
    %{
      id: a.id,
      name: Feed.term(a.name),
      module: inspect(a.module),
      host: host_id,
      node: node && to_string(node)
    }
  end

  defp agent_detail(id, req, ctx) do
    with {:ok, ref} <- agent_ref(id, ctx), :ok <- search_budget(ref, req, ctx) do
      case Tartarus.agent_info(ref) do
        {:ok, info} ->
          names = names(ctx)
          view = Map.new(info, fn {k, v} -> {k, info_value(k, v, names)} end)
          json(200, Map.put(view, :id, id))

        {:error, reason} ->
          if is_binary(ref) and reason == :not_found, do: missed(id, ctx)
          error(404, "unknown_agent", "agent #{id}: #{describe(reason)}")
      end
    end
  end

  # -- what a read may cost the overlay --------------------------------------------------

  # An agent not on the hosts shown is searched for through the overlay (Tartarus.whereis:
  # one walk that asks each reachable node once, within 2 s). Reads need no token, so what
  # they may cost the fleet is bounded per client address: an id that a search did not
  # find is answered 404 without a new search for ctx.search_miss_ms, and an address
  # starts at most ctx.search_rate searches per second (beyond: 429). Both are kept in
  # the cache table, old entries swept when new ones are written.
  defp search_budget(id, req, ctx) when is_binary(id) do
    now = Clock.machine_time(:millisecond)
    second = div(now, 1_000)

    case :ets.lookup(ctx.cache, {:missed, id}) do
      [{_, until}] when now < until ->
        error(
          404,
          "unknown_agent",
          "agent #{id}: #{describe(:not_found)} (a search less than #{ctx.search_miss_ms} ms ago did not find it)"
        )

      _ ->
        key = {:searches, Map.get(req, :peer), second}

        case :ets.update_counter(ctx.cache, key, 1, {key, 0}) do
          1 ->
            :ets.select_delete(ctx.cache, [
              {{{:searches, :_, :"$1"}, :_}, [{:<, :"$1", second}], [true]}
            ])

            :ok

          n when n <= ctx.search_rate ->
            :ok

          _ ->
            error(
              429,
              "too_many_searches",
              "agent #{id} is not on the hosts shown here, and this address has started #{ctx.search_rate} searches of the overlay in this second (at most #{ctx.search_rate} a second): try again in a second"
            )
        end
    end
  end

  defp search_budget(_id_on_a_known_host, _req, _ctx), do: :ok

  defp missed(id, ctx) do
    now = Clock.machine_time(:millisecond)
    :ets.select_delete(ctx.cache, [{{{:missed, :_}, :"$1"}, [{:<, :"$1", now}], [true]}])
    :ets.insert(ctx.cache, {{:missed, id}, now + ctx.search_miss_ms})
  end

  defp info_value(k, v, names) when k in [:host, :home, :source],
    do: Map.get(names, v) || Feed.host_id(v)

  defp info_value(:module, v, _) when is_atom(v), do: inspect(v)
  defp info_value(_k, v, _), do: Feed.term(v)

  defp names(ctx) do
    _ = topology(ctx)

    case :ets.lookup(ctx.cache, :names) do
      [{:names, names}] -> names
      _ -> %{}
    end
  end

  defp events(q, ctx) do
    with {:ok, since} <- int(q, "since", 0, 0, 1_000_000_000_000),
         {:ok, limit} <- int(q, "limit", 200, 1, 1_000) do
      type =
        case q["type"] do
          nil -> nil
          "" -> nil
          t -> Enum.find(event_types(), &(Atom.to_string(&1) == t)) || :__none__
        end

      f = %{
        since: since,
        limit: limit,
        type: type,
        host: blank(q["host"]),
        agent: blank(q["agent"])
      }

      json(200, Feed.events(ctx.feed, f))
    end
  end

  defp blank(""), do: nil
  defp blank(x), do: x

  defp event_types,
    do:
      ~w(created arrival departure move_failed clone kill stopped crash removed message refused dropped broadcast broadcast_received signal signal_relay)a

  defp catalog(ctx) do
    Enum.map(ctx.catalog, fn m ->
      %{module: inspect(m), doc: first_line(m)}
    end)
  end

  defp first_line(m) do
    case Code.fetch_docs(m) do
      {:docs_v1, _, _, _, %{"en" => doc}, _, _} -> doc |> String.split("\n") |> hd()
      _ -> ""
    end
  end

  defp panels(ctx) do
    case :ets.lookup(ctx.cache, :panels) do
      [{:panels, :kept, v}] -> v
      _ -> panels_now(ctx)
    end
  end

  defp panels_now(ctx) do
    Enum.map(ctx.panels, fn {m, a} ->
      v = m.render(a)

      %{
        name: m.name(a),
        title: v.title,
        text: Map.get(v, :text, ""),
        columns: v.columns,
        rows: Enum.map(v.rows, fn row -> Enum.map(row, &Feed.term/1) end),
        actions: Map.get(v, :actions, []),
        image: Panel.data_url(Map.get(v, :image)),
        image_alt: get_in(v, [Access.key(:image, %{}), Access.key(:alt, v.title)]) || v.title
      }
    end)
  end

  # -- the fleet, health and rates ---------------------------------------------------------

  defp fleet(ctx) do
    {snaps, at} =
      case ctx.fleet do
        nil -> {emulation_snapshots(ctx), now_ms()}
        f -> with(%{snapshots: s, at: at} <- Fleet.get(f), do: {s, at})
      end

    per_node = fleet_views(ctx)

    nodes =
      Enum.map(snaps, fn
        %{error: e} = snap ->
          %{
            node: to_string(snap.node),
            reachable: false,
            error: e,
            path: Enum.map(snap.path, &to_string/1)
          }

        snap ->
          mine = Map.get(per_node, to_string(snap.node), %{hosts: [], residents: 0, plugins: 0})

          %{
            node: to_string(snap.node),
            reachable: true,
            path: Enum.map(snap.path, &to_string/1),
            age_ms: if(snap.node == node(), do: 0, else: now_ms() - at),
            hosts: mine.hosts,
            agents: Map.get(snap, :agents_total, mine.residents),
            plugins: mine.plugins,
            health: health_view(snap.health)
          }
      end)

    %{nodes: nodes, gathered_at: at, age_ms: now_ms() - at, kept: frozen?(ctx)}
  end

  # The BEAM nodes of the hosts shown (this node first): in an emulation over peer nodes,
  # this node (the controller) and every peer.
  defp shown_nodes(ctx) do
    hosts = topology(ctx).hosts
    Enum.uniq([node() | Enum.map(hosts, &elem(&1.host, 1))])
  end

  # Without a fleet gather (an emulation), each node of the hosts shown gives its latest
  # health sample, all asked at once (the controller is connected to its peers), cached
  # as the views are.
  defp emulation_snapshots(ctx) do
    cached(ctx, :emulation_snapshots, fn ->
      others = shown_nodes(ctx) -- [node()]
      answers = :erpc.multicall(others, Health, :latest, [], 5_000)

      [%{node: node(), path: [node()], health: Health.latest()}] ++
        Enum.zip_with(others, answers, fn
          n, {:ok, health} ->
            %{node: n, path: [node(), n], health: health}

          n, {kind, reason} ->
            %{node: n, path: [node(), n], error: Fleet.describe_error(kind, reason)}
        end)
    end)
  end

  # Per node: its hosts' ids, residents and plugins, from the views (cached as they are).
  defp fleet_views(ctx) do
    cached(ctx, :fleet_views, fn ->
      ctx
      |> host_views()
      |> Enum.group_by(& &1.node)
      |> Map.new(fn {node, vs} ->
        {node,
         %{
           hosts: Enum.map(vs, & &1.id),
           residents: Enum.sum(Enum.map(vs, & &1.residents)),
           plugins: Enum.sum(Enum.map(vs, &length(&1.plugins)))
         }}
      end)
    end)
  end

  defp health_view(nil), do: nil
  defp health_view(sample), do: Map.delete(sample, :hosts)

  defp health(q, ctx) do
    with {:ok, points} <- int(q, "points", 300, 1, 3_600),
         {:ok, path} <- health_path(q["node"], ctx),
         {:ok, series} <- health_series(path, points, ctx) do
      node = List.last(path) |> to_string()

      # The sampler names a host by its name on its node; the page by its id (an
      # emulation's topology name, `h7`, for the host `emu00009E-h7`).
      ids = for h <- topology(ctx).hosts, into: %{}, do: {host_key(h.host), h.id}
      id_of = fn name -> Map.get(ids, {name, node}, name) end

      case blank(q["host"]) do
        nil ->
          json(200, %{
            node: node,
            points: Enum.map(series, &health_view/1),
            hosts:
              series
              |> Enum.flat_map(&Map.keys(&1.hosts))
              |> Enum.uniq()
              |> Enum.map(id_of)
              |> Enum.sort()
          })

        host ->
          name =
            case Map.fetch(index(ctx), host) do
              {:ok, h} -> h.host |> host_key() |> elem(0)
              :error -> host |> String.split("@") |> hd()
            end

          points = for p <- series, row = p.hosts[name], do: Map.put(row, :t, p.t)

          json(200, %{node: node, host: host, points: points})
      end
    end
  end

  defp host_key({name, node}), do: {to_string(name), to_string(node)}

  defp processes(q, ctx) do
    with {:ok, limit} <- int(q, "limit", 20, 1, 500),
         {:ok, sort} <- choice(q, "sort", Processes.sorts() |> Enum.sort_by(&(&1 != "memory"))),
         {:ok, path} <- health_path(q["node"], ctx) do
      case Fleet.forward(path, {:processes, sort, limit}) do
        {:ok, answer} ->
          json(200, answer)

        {:error, why} ->
          error(502, "node_unreachable", "cannot read #{List.last(path)}: #{why}")
      end
    end
  end

  defp health_path(nil, _ctx), do: {:ok, [node()]}
  defp health_path("", _ctx), do: {:ok, [node()]}

  defp health_path(name, ctx) do
    snaps = if ctx.fleet, do: Fleet.get(ctx.fleet).snapshots, else: emulation_snapshots(ctx)

    cond do
      name == to_string(node()) ->
        {:ok, [node()]}

      snap = Enum.find(snaps, &(to_string(&1.node) == name and not Map.has_key?(&1, :error))) ->
        {:ok, snap.path}

      true ->
        error(404, "unknown_node", "no node #{inspect(name)} is reachable through the overlay")
    end
  end

  defp health_series(path, points, ctx) do
    case frozen_health(ctx, path) do
      {:ok, series} ->
        {:ok, Enum.take(series, -points)}

      :none ->
        case Fleet.forward(path, {:health, points}) do
          {:ok, series} ->
            {:ok, series}

          {:error, why} ->
            error(502, "node_unreachable", "cannot read #{List.last(path)}: #{why}")
        end
    end
  end

  defp frozen_health(ctx, path) do
    case :ets.lookup(ctx.cache, {:frozen_health, List.last(path)}) do
      [{_, series}] -> {:ok, series}
      [] -> :none
    end
  end

  defp rates(q, ctx) do
    with {:ok, seconds} <- int(q, "seconds", 120, 1, 300) do
      json(200, Feed.rates(ctx.feed, seconds))
    end
  end

  defp frozen?(ctx), do: :ets.member(ctx.cache, :frozen)

  # What a kept page serves as it was when its run ended.
  @kept [:topology, :views, :agents, :index, :summary, :fleet_views, :emulation_snapshots]

  @doc false
  # Keeps what the page shows as it is now (a run that ended): the hosts, links, views,
  # agents, summary parts, panels and this node's (and the fleet's) health series are
  # computed once more and then served as they are until the dashboard stops.
  def freeze(ctx) do
    if ctx.fleet, do: Fleet.freeze(ctx.fleet)
    for k <- @kept, do: :ets.delete(ctx.cache, k)
    _ = topology(ctx)
    _ = host_views(ctx)
    _ = index(ctx)
    _ = cached(ctx, :agents, fn -> collect_agents(topology(ctx).hosts) end)
    _ = summary_views(ctx)
    _ = fleet_views(ctx)
    if ctx.fleet == nil, do: emulation_snapshots(ctx)
    :ets.insert(ctx.cache, {:panels, :kept, panels_now(ctx)})
    nodes = topology(ctx).hosts |> Enum.map(&elem(&1.host, 1)) |> Enum.uniq()

    for n <- Enum.uniq([node() | nodes]) do
      path = if n == node(), do: [node()], else: fleet_path(ctx, n)

      case path && Fleet.forward(path, {:health, 3_600}) do
        {:ok, series} -> :ets.insert(ctx.cache, {{:frozen_health, n}, series})
        _ -> :ok
      end
    end

    for k <- @kept do
      case :ets.lookup(ctx.cache, k) do
        [{^k, _until, v}] -> :ets.insert(ctx.cache, {k, :kept, v})
        _ -> :ok
      end
    end

    :ets.insert(ctx.cache, {:frozen})
    :ok
  end

  defp fleet_path(%{fleet: nil}, n), do: [node(), n]

  defp fleet_path(ctx, n) do
    case Enum.find(Fleet.get(ctx.fleet).snapshots, &(&1.node == n)) do
      %{path: p} -> p
      _ -> nil
    end
  end

  # -- actions --------------------------------------------------------------------------

  defp action(["agents"], p, ctx) do
    with {:ok, h} <- host_param(p, "host", ctx),
         {:ok, m} <- module_param(p, ctx) do
      create =
        if p["static"] == true,
          do: &Tartarus.create_static_agent/3,
          else: &Tartarus.create_mobile_agent/3

      case create.(h.host, m, Map.get(p, "args")) do
        {:ok, id} -> json(201, %{ok: true, id: id, host: h.id})
        {:error, reason} -> failed("create", reason)
      end
    end
  end

  defp action(["agents", id, "move"], p, ctx) do
    with {:ok, ref} <- agent_ref(id, ctx), {:ok, h} <- host_param(p, "to", ctx) do
      case Tartarus.move(ref, h.host) do
        :ok -> json(200, %{ok: true, id: id, host: h.id})
        {:error, reason} -> failed("move", reason)
      end
    end
  end

  defp action(["agents", id, "clone"], p, ctx) do
    with {:ok, ref} <- agent_ref(id, ctx),
         {:ok, dest} <- clone_dest(p, ctx) do
      case Tartarus.clone(ref, dest) do
        {:ok, clone} -> json(200, %{ok: true, id: id, clone: clone})
        {:error, reason} -> failed("clone", reason)
      end
    end
  end

  # The token was checked before the body was read (admit/2): the page asks when a token is
  # entered, rather than finding out at the first action.
  defp action(["token"], _p, _ctx), do: json(200, %{ok: true})

  defp action(["agents", id, "kill"], _p, ctx) do
    with {:ok, ref} <- agent_ref(id, ctx) do
      case Tartarus.kill(ref) do
        :ok -> json(200, %{ok: true, id: id})
        {:error, reason} -> failed("kill", reason)
      end
    end
  end

  defp action(["agents", id, "post"], p, ctx) do
    with {:ok, ref} <- agent_ref(id, ctx),
         {:ok, msg} <- message_param(p) do
      case Tartarus.post(ref, msg) do
        :ok -> json(200, %{ok: true, id: id, message: inspect(msg)})
        {:error, reason} -> failed("post", reason)
      end
    end
  end

  # A request: the agent's reply, as Elixir text (inspect) and, when it is plain data, as
  # JSON-able data.
  defp action(["agents", id, "request"], p, ctx) do
    with {:ok, ref} <- agent_ref(id, ctx),
         {:ok, msg} <- message_param(p),
         {:ok, timeout} <- timeout_param(p) do
      case Tartarus.request(ref, msg, timeout) do
        {:ok, reply} ->
          json(200, %{ok: true, id: id, message: inspect(msg), reply: inspect(reply, limit: 50)})

        {:error, reason} ->
          failed("request", reason)
      end
    end
  end

  defp action(["links", act], p, ctx) do
    with {:ok, emu} <- emulation(ctx),
         {:ok, a} <- host_param(p, "a", ctx),
         {:ok, b} <- host_param(p, "b", ctx) do
      emu_act(emu, String.to_existing_atom(act <> "_link"), %{a: a.id, b: b.id}, ctx)
    end
  end

  defp action(["hosts", id, act], _p, ctx) do
    with {:ok, emu} <- emulation(ctx), {:ok, h} <- find_host(id, ctx) do
      emu_act(emu, String.to_existing_atom(act), %{host: h.id}, ctx)
    end
  end

  defp action(["panels", name, act], p, ctx) do
    case Enum.find(ctx.panels, fn {m, a} -> m.name(a) == name end) do
      nil ->
        error(404, "unknown_panel", "there is no panel named #{inspect(name)}")

      {m, a} ->
        case m.act(a, act, p) do
          {:ok, result} -> json(200, %{ok: true, result: Feed.term(result)})
          {:error, reason} -> failed(act, reason)
        end
    end
  end

  defp emu_act({m, a}, act, params, ctx) do
    case m.act(a, act, params) do
      :ok ->
        :ets.delete(ctx.cache, :topology)
        :ets.delete(ctx.cache, :views)
        json(200, Map.put(params, :ok, true))

      {:error, reason} ->
        failed(Atom.to_string(act), reason)
    end
  end

  defp emulation(%{emulation: nil}),
    do: error(404, "not_emulated", "this node runs no emulation: link actions need one")

  defp emulation(%{emulation: emu}), do: {:ok, emu}

  # -- input ----------------------------------------------------------------------------

  defp authorize(req, ctx) do
    given =
      case req.headers do
        %{"authorization" => "Bearer " <> t} -> String.trim(t)
        %{"x-tartarus-token" => t} -> String.trim(t)
        _ -> nil
      end

    cond do
      given in [nil, ""] ->
        {:error, 401, "token_required",
         "this action needs the dashboard's token (Authorization: Bearer TOKEN); without it the dashboard is read-only"}

      byte_size(given) == byte_size(ctx.token) and :crypto.hash_equals(given, ctx.token) ->
        :ok

      true ->
        {:error, 403, "bad_token", "the token is wrong: the action was refused"}
    end
  end

  defp params(%{body: body}) do
    case String.trim(body) do
      "" ->
        {:ok, %{}}

      text ->
        case JSON.decode(text) do
          {:ok, map} when is_map(map) ->
            {:ok, map}

          {:ok, _} ->
            {:error, 400, "bad_json", "the body must be a JSON object"}

          {:error, {:invalid_json, pos}} ->
            {:error, 400, "bad_json", "the body is not valid JSON (at byte #{pos})"}
        end
    end
  end

  # A message: `term`, an Elixir literal read as data (TartarusDashboard.Term), or
  # `message`, any JSON value as it decodes.
  defp message_param(%{"term" => text}) when is_binary(text) do
    case Term.parse(text) do
      {:ok, term} -> {:ok, term}
      {:error, why} -> reply_error({:error, 400, "bad_term", why})
    end
  end

  defp message_param(%{"term" => _}),
    do: reply_error({:error, 400, "bad_param", "\"term\" must be a string (Elixir text)"})

  defp message_param(p) do
    case Map.fetch(p, "message") do
      {:ok, v} ->
        {:ok, v}

      :error ->
        reply_error(
          {:error, 400, "missing_param",
           "the body needs a \"term\" (Elixir text) or a \"message\" (JSON) field"}
        )
    end
  end

  defp timeout_param(p) do
    case Map.get(p, "timeout_ms", 5_000) do
      ms when is_integer(ms) and ms > 0 and ms <= 60_000 ->
        {:ok, ms}

      other ->
        reply_error(
          {:error, 400, "bad_param",
           "timeout_ms must be an integer in 1..60000, got: #{JSON.encode!(other)}"}
        )
    end
  end

  defp host_param(p, key, ctx) do
    case p[key] do
      id when is_binary(id) ->
        find_host(id, ctx)

      nil ->
        reply_error(
          {:error, 400, "missing_param", "the body needs a #{inspect(key)} field (a host id)"}
        )

      other ->
        reply_error(
          {:error, 400, "bad_param",
           "#{inspect(key)} must be a host id (a string), got: #{JSON.encode!(other)}"}
        )
    end
  end

  defp clone_dest(%{"to" => "here"}, _ctx), do: {:ok, :here}
  defp clone_dest(%{"to" => nil}, _ctx), do: {:ok, :here}
  defp clone_dest(p, ctx), do: with({:ok, h} <- host_param(p, "to", ctx), do: {:ok, h.host})

  defp module_param(p, ctx) do
    case p["module"] do
      name when is_binary(name) ->
        case Enum.find(ctx.catalog, &(inspect(&1) == name or inspect(&1) == "Elixir." <> name)) do
          nil ->
            reply_error(
              {:error, 404, "unknown_module",
               "#{inspect(name)} is not in this node's catalog: #{Enum.map_join(ctx.catalog, ", ", &inspect/1)}"}
            )

          m ->
            {:ok, m}
        end

      _ ->
        reply_error(
          {:error, 400, "missing_param",
           "the body needs a \"module\" field (from GET /api/catalog)"}
        )
    end
  end

  # A host by its id, by `name@node`, or by a short name that several hosts share: the
  # platform then resolves it through the overlay (Tartarus.Host.resolve/2) or says it is
  # ambiguous.
  defp find_host(id, ctx) do
    case Map.fetch(index(ctx), id) do
      {:ok, h} ->
        {:ok, h}

      :error ->
        case Enum.filter(topology(ctx).hosts, &short_name?(&1.host, id)) do
          [_, _ | _] -> {:ok, %{id: id, host: String.to_existing_atom(id), up: true}}
          _ -> error(404, "unknown_host", "there is no host #{inspect(id)}")
        end
    end
  end

  defp short_name?({name, _node}, id) when is_atom(name), do: Atom.to_string(name) == id
  defp short_name?(_, _), do: false

  defp agent_ref(id, ctx) do
    cond do
      not Regex.match?(@id, id) ->
        error(400, "bad_agent_id", "#{inspect(id)} is not an agent id (16 hexadecimal digits)")

      (place = Feed.place(ctx.feed, id)) && Map.has_key?(index(ctx), place) ->
        {:ok, {id, Map.fetch!(index(ctx), place).host}}

      a =
          Enum.find(
            cached(ctx, :agents, fn -> collect_agents(topology(ctx).hosts) end),
            &(&1.id == id)
          ) ->
        {:ok, {id, Map.fetch!(index(ctx), a.host).host}}

      ctx.fleet != nil ->
        # Not seen on the hosts shown: the platform looks for it through the overlay.
        {:ok, id}

      true ->
        error(404, "unknown_agent", "there is no agent #{id} on the hosts shown here")
    end
  end

  defp with_query(req, fun) do
    case fun.(req.query) do
      {:error, status, code, message} -> error(status, code, message)
      other -> other
    end
  end

  defp int(q, key, default, min, max) do
    case q[key] do
      nil ->
        {:ok, default}

      s ->
        case Integer.parse(s) do
          {n, ""} when n >= min and n <= max ->
            {:ok, n}

          _ ->
            reply_error(
              {:error, 400, "bad_param",
               "#{key} must be an integer in #{min}..#{max}, got: #{inspect(s)}"}
            )
        end
    end
  end

  defp choice(q, key, values) do
    case q[key] do
      nil ->
        {:ok, hd(values)}

      v ->
        if v in values,
          do: {:ok, v},
          else:
            reply_error(
              {:error, 400, "bad_param",
               "#{key} must be one of #{Enum.join(values, ", ")}, got: #{inspect(v)}"}
            )
    end
  end

  # Inside `with` chains an error must stop the chain and be the answer itself.
  defp reply_error({:error, status, code, message}), do: error(status, code, message)

  # -- the topology and host views, cached for a second -----------------------------------

  @doc false
  # The hosts and links shown (cached for a second). The feed learns which id stands for
  # which host address, so that events name hosts as the page does.
  def topology(ctx) do
    cached(ctx, :topology, fn ->
      topo = topology_now(ctx)
      names = Map.new(topo.hosts, &{&1.host, &1.id})

      case :ets.lookup(ctx.cache, :names) do
        [{:names, ^names}] ->
          :ok

        _ ->
          :ets.insert(ctx.cache, {:names, names})
          Feed.names(ctx.feed, names)
      end

      topo
    end)
  end

  defp topology_now(ctx) do
    case ctx.emulation do
      {m, a} ->
        hosts = m.hosts(a)
        Feed.watch_nodes(ctx.feed, Enum.map(hosts, &elem(&1.host, 1)))
        %{hosts: hosts, links: m.links(a)}

      nil ->
        fleet_topology(ctx)
    end
  end

  # This node's hosts and, through the fleet's gather, those of every node the overlay
  # reaches; a host is named by its name, or `name@node` when another host has that name.
  defp fleet_topology(ctx) do
    local = Enum.map(Tartarus.hosts(), fn h -> %{host: h, up: true, remote: nil} end)
    fleet = if ctx.fleet, do: Fleet.get(ctx.fleet), else: %{snapshots: [], at: now_ms()}

    remote =
      for snap <- fleet.snapshots,
          snap.node != node(),
          by_host = Enum.group_by(Map.get(snap, :agents, []), & &1.host),
          h <- Map.get(snap, :hosts, []),
          do: %{
            host: {h.name, h.node},
            up: true,
            remote: h,
            agents: Map.get(by_host, h.name, []),
            seen_at: fleet.at
          }

    all = local ++ remote
    counts = Enum.frequencies_by(all, fn h -> elem(h.host, 0) end)

    hosts =
      Enum.map(all, fn %{host: {name, node}} = h ->
        id =
          if counts[name] == 1 or h.remote == nil,
            do: to_string(name),
            else: "#{name}@#{node}"

        Map.put(h, :id, id)
      end)

    ids = Map.new(hosts, &{&1.host, &1.id})

    links =
      for h <- hosts,
          n <- if(h.remote, do: h.remote.neighbours, else: neighbours(h.host)),
          b = Map.get(ids, n),
          b != nil and h.id < b,
          do: %{a: h.id, b: b, up: true, cross: elem(h.host, 1) != elem(n, 1)}

    %{hosts: hosts, links: Enum.uniq(links)}
  end

  defp now_ms, do: Clock.machine_system_time(:millisecond)

  defp neighbours(h) do
    case Tartarus.neighbours(h) do
      list when is_list(list) -> list
      _ -> []
    end
  end

  defp index(ctx) do
    cached(ctx, :index, fn ->
      hosts = topology(ctx).hosts
      full = Map.new(hosts, fn %{host: {name, node}} = h -> {"#{name}@#{node}", h} end)
      Map.merge(full, Map.new(hosts, &{&1.id, &1}))
    end)
  end

  # Up to @status_limit hosts, each host's view comes from Tartarus.status/1. Beyond,
  # the whole status is too dear (it also lists the host's plugins and forwarding
  # pointers), so the view takes only the residents and counters (Tartarus.status/2).
  # Both are counted since the host started.
  @status_limit 500

  defp host_views(ctx) do
    cached(ctx, :views, fn ->
      hosts = topology(ctx).hosts

      {remote, local} = Enum.split_with(hosts, &Map.get(&1, :remote))

      local =
        if length(local) <= @status_limit do
          Enum.map(local, &host_view/1)
        else
          Enum.map(local, &light_view/1)
        end

      local ++ Enum.map(remote, &remote_view/1)
    end)
  end

  @light_counts [:arrivals, :departures, :refused, :messages, :move_failed, :bytes]

  defp light_view(h) do
    {residents, counts} =
      case h.up && Tartarus.status(h.host, [:resident, :counts]) do
        %{resident: r, counts: c} -> {r, Map.take(c, @light_counts)}
        _ -> {0, %{}}
      end

    h
    |> base_view("host")
    |> Map.merge(counts)
    |> Map.put(:residents, residents)
  end

  defp base_view(h, counted) do
    %{
      id: h.id,
      node: to_string(elem(h.host, 1)),
      up: h.up,
      pos: pos(Map.get(h, :pos)),
      floor: Map.get(h, :floor),
      counted: counted,
      residents: 0,
      arrivals: 0,
      departures: 0,
      refused: 0,
      bytes: 0,
      messages: 0,
      move_failed: 0,
      hop_median_us: nil,
      hop_p99_us: nil,
      age_ms: 0,
      plugins: []
    }
  end

  # A host of another node, as its node's snapshot gave it (`age_ms`: how old the gather is).
  defp remote_view(%{remote: r} = h) do
    h
    |> base_view("host")
    |> Map.merge(
      Map.take(
        r,
        ~w(residents arrivals departures refused bytes messages move_failed hop_median_us hop_p99_us)a
      )
    )
    |> Map.merge(%{age_ms: now_ms() - h.seen_at, plugins: Enum.map(r.plugins, &plugin_view/1)})
  end

  defp plugin_view(p) do
    %{
      name: Atom.to_string(p.name),
      kind: Feed.term(p.kind),
      capabilities: Enum.map(p.capabilities, &Feed.term/1),
      last: Feed.term(p.last),
      last_at: p.last_at
    }
  end

  defp local_plugins({name, _} = host, plugins) do
    Enum.map(plugins, fn {pname, desc} ->
      last = if elem(host, 1) == node(), do: Tartarus.Plugin.last_reading(name, pname)

      plugin_view(%{
        name: pname,
        kind: Map.get(desc, :kind),
        capabilities: Map.get(desc, :capabilities, []),
        last: last && last.value,
        last_at: last && last.at
      })
    end)
  end

  defp host_view(h) do
    base = base_view(h, "host")

    case h.up && Tartarus.status(h.host) do
      %{counts: _} = st ->
        base
        |> Map.merge(Fleet.counters(st))
        |> Map.put(:plugins, local_plugins(h.host, Map.get(st, :plugins, [])))

      _ ->
        base
    end
  end

  defp pos({x, y}) when is_number(x) and is_number(y), do: [x, y]
  defp pos(_), do: nil

  # A value is kept for a second, or for ten times what computing it took if that is
  # longer: however often pages ask, recomputing takes at most a tenth of one core (10,000
  # hosts' statuses are not read again for every request).
  defp cached(ctx, key, fun) do
    now = Clock.machine_time(:millisecond)

    case :ets.lookup(ctx.cache, key) do
      [{^key, :kept, value}] ->
        value

      [{^key, until, value}] when now < until ->
        value

      _ ->
        value = fun.()
        took = Clock.machine_time(:millisecond) - now
        :ets.insert(ctx.cache, {key, now + max(@cache_ms, 10 * took), value})
        value
    end
  end

  # -- answers --------------------------------------------------------------------------

  defp json(status, data), do: {status, "application/json", JSON.encode!(data)}

  defp error(status, code, message),
    do: {status, "application/json", JSON.encode!(%{error: code, message: message})}

  defp failed(what, reason),
    do: error(422, "action_failed", "#{what} failed: #{describe(reason)}")

  @doc false
  def describe(:not_found), do: "no such agent (it may have stopped)"
  def describe({:no_link, h}), do: "there is no live link to #{Feed.host_id(h)}"
  def describe({:unknown_host, h}), do: "unknown host #{Feed.host_id(h)}"

  def describe({:ambiguous_host, name, hosts}),
    do:
      "#{name} names several hosts (#{Enum.map_join(hosts, ", ", fn {n, node} -> "#{n}@#{node}" end)}): give one as name@node"

  def describe({:refused, r}), do: "the destination refused it (#{describe(r)})"
  def describe(:timeout), do: "no answer in time"

  def describe({:no_such_link, a, b}),
    do: "there is no link between #{Feed.host_id(a)} and #{Feed.host_id(b)}"

  def describe(r) when is_binary(r), do: r
  def describe(r) when is_atom(r), do: r |> Atom.to_string() |> String.replace("_", " ")
  def describe(r), do: inspect(r, limit: 8, printable_limit: 100)
end
