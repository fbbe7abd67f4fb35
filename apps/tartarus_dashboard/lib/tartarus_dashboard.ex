defmodule TartarusDashboard do
  @schema [
    port: [type: :non_neg_integer, default: 0, doc: "TCP port (0: any free port)"],
    bind: [
      type: :any,
      default: {127, 0, 0, 1},
      doc: "address to listen on, a tuple (`{0, 0, 0, 0}` for every interface)"
    ],
    token: [type: :any, doc: "the action token (a string); default: a random one"],
    token_file: [
      type: :any,
      doc: "read the token from this file (its first line) instead of making one"
    ],
    catalog: [
      type: {:list, :atom},
      default: [Tartarus.Examples.Echo],
      doc: "agent modules the page may create"
    ],
    emulation: [
      type: :any,
      doc: "`{module, arg}`: a `TartarusDashboard.Emulation` (hosts, links, link actions)"
    ],
    panels: [
      type: :any,
      default: [],
      doc: "`[{module, arg}]`: `TartarusDashboard.Panel`s shown below the graph"
    ],
    batch_ms: [
      type: :pos_integer,
      default: 1_000,
      doc: "how often the live stream sends a batch (the page draws at most once a second)"
    ],
    max_batch: [
      type: :pos_integer,
      default: 200,
      doc: "events per batch at most (the rest are counted as dropped)"
    ],
    recent: [type: :pos_integer, default: 1_000, doc: "recent events kept for `/api/events`"],
    max_body: [
      type: :pos_integer,
      default: 16_384,
      doc: "largest request body accepted, bytes (chunked or not)"
    ],
    hosts: [
      type: {:list, :string},
      default: [],
      doc:
        "names besides `localhost`, the loopback addresses and the address a client connected to that the `Host` and `Origin` headers may give (e.g. `[\"pi.local\"]`)"
    ],
    idle_timeout: [
      type: :pos_integer,
      default: 30_000,
      doc:
        "ms a connection may wait for its next request line (or take nothing of an answer) before it is closed"
    ],
    request_timeout: [
      type: :pos_integer,
      default: 10_000,
      doc: "ms from a request line to the last byte of its body (else 408 and the close)"
    ],
    max_clients: [type: :pos_integer, default: 200, doc: "connections served at once"],
    health: [
      type: :boolean,
      default: true,
      doc: "sample this node's health (`TartarusDashboard.Health`) for the page's charts"
    ],
    fleet: [
      type: :boolean,
      default: true,
      doc: "without an emulation, show every node the overlay reaches (`TartarusDashboard.Fleet`)"
    ],
    fleet_ttl: [
      type: :pos_integer,
      default: 8,
      doc: "overlay hops the fleet's gather goes at most"
    ],
    fleet_ms: [
      type: :pos_integer,
      default: 2_000,
      doc: "how old the fleet's last gather may be before a request starts the next"
    ],
    max_per_client: [
      type: :pos_integer,
      default: 16,
      doc: "connections served at once from one client address (beyond: 503 and the close)"
    ],
    search_rate: [
      type: :pos_integer,
      default: 2,
      doc:
        "overlay searches per second one client address may start (`GET /api/agents/ID` of an agent not on the hosts shown; beyond: 429)"
    ],
    search_miss_ms: [
      type: :pos_integer,
      default: 5_000,
      doc: "ms an id that an overlay search did not find is answered 404 without a new search"
    ]
  ]

  @moduledoc """
  A live web dashboard for a node: the overlay graph, its agents, per-host counters, hop
  times, a stream of recent events and actions, served by a small HTTP/1.1 server on
  `:gen_tcp` (no dependency outside OTP). `docs/dashboard.md` is the user guide and documents the JSON
  HTTP API the page uses (programs in any language can drive a node through it).

      {:ok, dash} = TartarusDashboard.start_link(port: 4040)
      TartarusDashboard.url(dash)     # "http://127.0.0.1:4040/"
      TartarusDashboard.token(dash)   # what actions need (Authorization: Bearer ...)

  `mix tartarus.node --dashboard PORT`, `mix tartarus.emu --dashboard PORT` and the
  scenarios' mix tasks (through `TartarusEmu.Scenario`'s `:dashboard` option) start one.

  ## Options

  #{Tartarus.Options.docs(@schema)}

  ## What it reads and what it changes

  Hosts are those of this node (`Tartarus.hosts/0`, with the neighbour links among them)
  unless an `:emulation` is given, which then names the hosts and links (on any BEAM node)
  and carries out the link actions (break, heal, isolate, rejoin). Counters come from
  `Tartarus.status/1`, agents from `Tartarus.agents/1`, and every action goes through the
  public `Tartarus` API (`create_mobile_agent/4`, `move/2`, `clone/2`, `kill/1`, `post/3`).

  ## Live updates, and never slowing the platform

  One process (`TartarusDashboard.Feed`) subscribes to `Tartarus.Events` with a budget:
  the platform sends it at most `:max_batch` events per `:batch_ms` and skips the rest
  without a message; the counts per type come from the platform's own count of every event
  (`Tartarus.Events.type_totals/0`), so they are exact. Per event received it does a few map
  updates (last known place of each agent, a bounded ring of recent events, a bounded sample
  of hop times). Every `:batch_ms` it sends the connected pages one batch of those events
  (server-sent events on `/api/stream`); what was skipped is counted, not queued. A page that
  does not read fast enough gets no more batches until it catches up: the platform never
  waits for the dashboard.

  ## Security

  It listens on 127.0.0.1 by default. Reading needs nothing; every action needs the token
  (`Authorization: Bearer TOKEN` or `X-Tartarus-Token: TOKEN`), printed at start or read
  from `:token_file`. Without it the page is read-only: actions answer 401 (no token) or 403
  (a wrong one). Request bodies are JSON, at most `:max_body` bytes; decoded JSON never
  creates atoms (hosts, agents and modules are looked up among those that exist).

  The HTTP layer (`TartarusDashboard.Http`) checks before it reads any body:

    * the `Host` header, and the `Origin` header when sent, must name this dashboard:
      `localhost`, `127.0.0.1`, `[::1]`, the address the client connected to, or one of
      `:hosts`, with this port if a port is given; else 403 (`bad_host`, `bad_origin`). A
      page on another site whose name resolves to this machine (DNS rebinding) is refused;
    * an action's token (401, 403), then a declared `Content-Length` above `:max_body` (413).

  Bodies are read with the `:max_body` limit whatever the framing: a chunked body is
  refused with 413 as soon as it goes over. An answer given before the body is read closes
  the connection (after discarding at most 2 s or 1 MiB of what the client still sends,
  so that it reads the answer); nothing of a refused body is kept. A connection waits at
  most `:idle_timeout` for a request line and a request takes at most `:request_timeout`
  from its line to its body's last byte (408, then the close). At most `:max_per_client`
  connections are served at once from one address and at most `:max_clients` in all,
  shared fairly between addresses (a connection from an address holding fewer takes a slot
  of the address holding the most); beyond, 503 and the close, nothing read. A request
  line or header line is at most 8 KiB (414, 431), a request has at most 100 header lines,
  a `Content-Length` is digits alone, a request target's percent-encoding must decode to
  UTF-8 (400); chunked trailers are read and ignored.

  `GET /api/agents/ID` of an agent not on the hosts shown searches the overlay
  (`Tartarus.whereis/1`); reads need no token, so a miss is remembered for
  `:search_miss_ms` and one client address starts at most `:search_rate` searches a second
  (429 beyond).
  """

  use GenServer

  alias TartarusDashboard.{Api, Feed, Fleet, Health, Http}

  @typedoc "A running dashboard (its process)."
  @type t :: GenServer.server()

  @doc "The options' schema (see the moduledoc)."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Starts a dashboard linked to the caller. Returns `{:ok, pid}` or `{:error, reason}`
  (bad options, port in use, unreadable token file).
  """
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts \\ []) do
    with {:ok, opts} <- validate(opts), do: GenServer.start_link(__MODULE__, opts)
  end

  @doc "As `start_link/1`, not linked."
  @spec start(keyword()) :: GenServer.on_start()
  def start(opts \\ []) do
    with {:ok, opts} <- validate(opts), do: GenServer.start(__MODULE__, opts)
  end

  @doc """
  Stops a dashboard: the HTTP server, its connections and streams, its event subscription.

  When pages are kept (`keep_pages/0`, the `--dashboard-keep` flag of every mix task with
  `--dashboard`), it keeps the page instead (`keep/1`) and the task, once it has printed its
  results, waits until the user stops it (Ctrl-C), so that the run's last state and charts
  stay readable.
  """
  @spec stop(t()) :: :ok
  def stop(dash) do
    if :persistent_term.get({__MODULE__, :keep_pages}, false) do
      :ok = keep(dash)
      wait_at_exit(url(dash))
    else
      GenServer.stop(dash)
    end
  end

  @doc """
  From now on, `stop/1` keeps a dashboard's page (see `stop/1`) rather than stopping it: what
  `--dashboard-keep` does (the mix tasks' command-line parser calls it).
  """
  @spec keep_pages() :: :ok
  def keep_pages, do: :persistent_term.put({__MODULE__, :keep_pages}, true)

  # Once per node: after the task's own output, say where the page is and wait for Ctrl-C.
  defp wait_at_exit(url) do
    unless :persistent_term.get({__MODULE__, :waiting}, false) do
      :persistent_term.put({__MODULE__, :waiting}, true)

      System.at_exit(fn _ ->
        IO.puts(
          :standard_error,
          "dashboard: the run is over; its page stays readable at #{url} until you stop this task (Ctrl-C)"
        )

        Tartarus.Clock.machine_sleep(:infinity)
      end)
    end

    :ok
  end

  @doc """
  Keeps the page as it is now, for a run that has ended: the hosts, links, agents, panels
  and health series are read once more and then served unchanged until the dashboard stops
  (the page says "run over, kept"). Call it before the run's hosts stop.
  """
  @spec keep(t()) :: :ok
  def keep(dash), do: GenServer.call(dash, :keep, 120_000)

  @doc "The page's address, e.g. `\"http://127.0.0.1:4040/\"`."
  @spec url(t()) :: String.t()
  def url(dash), do: GenServer.call(dash, :url)

  @doc "The TCP port it listens on."
  @spec port(t()) :: :inet.port_number()
  def port(dash), do: GenServer.call(dash, :port)

  @doc "The token that actions need."
  @spec token(t()) :: String.t()
  def token(dash), do: GenServer.call(dash, :token)

  @doc """
  One line to print when a dashboard starts: where it is and the token.
  """
  @spec banner(t()) :: String.t()
  def banner(dash) do
    "dashboard: #{url(dash)}  (actions need the token: #{token(dash)})"
  end

  @doc """
  A GET with OTP's `:httpc` (for benchmarks and scripts that read the API from Elixir):
  `{:ok, status, body}` or `{:error, reason}`.
  """
  @spec http_get(String.t(), timeout()) :: {:ok, pos_integer(), binary()} | {:error, term()}
  def http_get(url, timeout \\ 60_000) do
    {:ok, _} = Application.ensure_all_started(:inets)

    case :httpc.request(:get, {String.to_charlist(url), []}, [timeout: timeout],
           body_format: :binary,
           socket_opts: [nodelay: true]
         ) do
      {:ok, {{_, status, _}, _headers, body}} -> {:ok, status, body}
      {:error, reason} -> {:error, reason}
    end
  end

  defp validate(opts) do
    with {:ok, opts} <- Tartarus.Options.validate(opts, @schema, "TartarusDashboard"),
         {:ok, token} <- token_of(opts) do
      {:ok, Keyword.put(opts, :token, token)}
    end
  end

  defp token_of(opts) do
    cond do
      is_binary(opts[:token]) and byte_size(opts[:token]) >= 8 ->
        {:ok, opts[:token]}

      opts[:token] != nil ->
        {:error,
         "invalid options given to TartarusDashboard for key [:token]: " <>
           "expected a string of at least 8 bytes, got: #{inspect(opts[:token])}"}

      opts[:token_file] != nil ->
        case File.read(opts[:token_file]) do
          {:ok, text} ->
            case text |> String.split("\n") |> hd() |> String.trim() do
              t when byte_size(t) >= 8 -> {:ok, t}
              _ -> {:error, "token file #{opts[:token_file]}: first line is shorter than 8 bytes"}
            end

          {:error, reason} ->
            {:error, "token file #{opts[:token_file]}: #{:file.format_error(reason)}"}
        end

      true ->
        {:ok, Base.url_encode64(:crypto.strong_rand_bytes(18), padding: false)}
    end
  end

  @impl true
  def init(opts) do
    Process.flag(:trap_exit, true)
    {:ok, feed} = Feed.start_link(opts)
    if opts[:health], do: Health.ensure_started()

    fleet =
      if opts[:fleet] and opts[:emulation] == nil do
        {:ok, f} = Fleet.start_link(ttl: opts[:fleet_ttl], fleet_ms: opts[:fleet_ms])
        f
      end

    ctx = %{
      feed: feed,
      token: opts[:token],
      catalog: opts[:catalog],
      emulation: opts[:emulation],
      panels: opts[:panels],
      fleet: fleet,
      max_body: opts[:max_body],
      search_rate: opts[:search_rate],
      search_miss_ms: opts[:search_miss_ms],
      cache: :ets.new(:tartarus_dashboard_cache, [:public, :set, read_concurrency: true])
    }

    conf =
      opts
      |> Keyword.take(
        ~w(bind port max_body idle_timeout request_timeout max_clients max_per_client)a
      )
      |> Map.new()
      |> Map.merge(%{ctx: ctx, hosts: Enum.map(opts[:hosts], &String.downcase/1)})

    case Http.start_link(conf) do
      {:ok, http} ->
        port = Http.port(http)
        # The first look at the hosts tells the feed their ids (see Api.topology/1).
        _ = Api.topology(ctx)
        host = opts[:bind] |> :inet.ntoa() |> to_string()
        {:ok, %{http: http, port: port, feed: feed, token: opts[:token], host: host, ctx: ctx}}

      {:error, reason} ->
        Feed.stop(feed)
        {:stop, reason}
    end
  end

  @impl true
  def handle_call(:url, _from, s), do: {:reply, "http://#{s.host}:#{s.port}/", s}
  def handle_call(:port, _from, s), do: {:reply, s.port, s}
  def handle_call(:token, _from, s), do: {:reply, s.token, s}
  def handle_call(:keep, _from, s), do: {:reply, Api.freeze(s.ctx), s}

  @impl true
  def handle_info({:EXIT, _pid, reason}, s), do: {:stop, reason, s}
  def handle_info(_other, s), do: {:noreply, s}

  @impl true
  def terminate(_reason, s) do
    Http.stop(s.http)
    Feed.stop(s.feed)
    :ok
  end
end
