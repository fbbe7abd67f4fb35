defmodule Tartarus.Host.Supervisor do
  @moduledoc false
  # One host's process tree:
  #
  #   Host.Supervisor        :rest_for_one, at most @max_restarts restarts in @max_seconds s
  #   ├── Host.Warden        owns the ledger and store tables, the journal and the callback
  #   │                      watchdog: what must outlive the server (Tartarus.Host.Warden)
  #   ├── Host.Server        adopts arrivals; starts, monitors, restarts and (when the host
  #   │                      stops) kills the host's agents
  #   ├── Overlay.Host       the host's signals, relays, broadcasts (Tartarus.Overlay)
  #   ├── plugins            DynamicSupervisor of the host's plugins
  #   └── Host.Keeper        brings a restarted host back (see below)
  #
  # The warden comes first because it owns the tables the agents and plugins use and the
  # journal; the server follows; the plugins' supervisor after them, so on shutdown plugins
  # stop before their tables disappear; the server kills its agents in its terminate/2 and
  # the warden, last, any left (Tartarus.Host.Warden). Agents are not a supervisor's
  # children: a create or an arrival would otherwise wait on one more process (the
  # supervisor's start_child call and the child's start handshake) on the path of every hop.
  #
  # :rest_for_one: a server that dies (a crash, or an untrappable :kill) is restarted with
  # the children after it, beside the same warden: the tables, the journal and the agents
  # live on, and the new server adopts the agents (Tartarus.Host.Server's init). Only the
  # warden's own death means a fresh host (its tables go with it).
  #
  # A host whose children crash more than @max_restarts times in @max_seconds seconds
  # stops for good (its supervisor is a temporary child of the node's hosts supervisor, so
  # no other host is touched). The keeper, last, tells a restart from the first start (a
  # counter shared by every incarnation of the children of this supervisor): on the first
  # start Tartarus.start_host/2 attaches the plugins, links the neighbours and restores
  # persisted agents itself; after a restart the keeper attaches the plugins and links the
  # neighbours again from the host's start options (the agents were adopted). Links added
  # after the start (by Tartarus.connect/3 from elsewhere) are not remembered across a
  # restart.
  use Supervisor

  @max_restarts 3
  @max_seconds 5

  def start_link({name, opts}) do
    Supervisor.start_link(__MODULE__, {name, opts}, name: via(:host_sup, name))
  end

  def via(kind, name), do: Tartarus.Host.via(kind, name)

  @impl true
  def init({name, opts}) do
    starts = :atomics.new(1, [])

    children = [
      %{id: :warden, start: {Tartarus.Host.Warden, :start_link, [{name, opts}]}},
      {Tartarus.Host.Server, {name, opts}},
      %{id: :overlay, start: {Tartarus.Overlay.Host, :start_link, [name]}},
      %{
        id: :plugins,
        start:
          {DynamicSupervisor, :start_link, [[strategy: :one_for_one, name: via(:plugins, name)]]},
        type: :supervisor
      },
      %{id: :keeper, start: {Tartarus.Host.Keeper, :start_link, [{name, opts, starts}]}}
    ]

    Supervisor.init(children,
      strategy: :rest_for_one,
      max_restarts: @max_restarts,
      max_seconds: @max_seconds
    )
  end
end

defmodule Tartarus.Host.Keeper do
  @moduledoc false
  # The last child of a host's supervisor: after a restart of the host's children it restores
  # the host (plugins, neighbours from the start options; the agents the new server adopted,
  # or persisted ones the journal still held); see Tartarus.Host.Supervisor. It expects no message: anything it receives is dropped and
  # counted.
  use GenServer
  require Logger

  def start_link({name, opts, starts}), do: GenServer.start_link(__MODULE__, {name, opts, starts})

  @impl true
  def init({name, opts, starts}) do
    # Trapping exits, so that terminate/2 runs when the host's supervisor stops its children
    # (the keeper first: it is the last child).
    Process.flag(:trap_exit, true)
    state = %{host: {name, node()}, opts: opts}

    case :atomics.add_get(starts, 1, 1) do
      1 ->
        {:ok, state}

      _restart ->
        # The mark its predecessor left when it stopped (terminate/2): the host runs again.
        with {:ok, info} <- Tartarus.Host.local(state.host),
             do: Tartarus.Ledger.clear_stopping(info)

        {:ok, state, {:continue, :recover}}
    end
  end

  @impl true
  def handle_continue(:recover, %{host: host, opts: opts} = state) do
    plugins =
      Enum.map(opts[:plugins] || [], fn {n, spec} ->
        Tartarus.Host.OnNode.attach_plugin(host, n, spec)
      end)

    links =
      Enum.map(opts[:neighbours] || [], fn n -> Tartarus.Host.Links.connect(host, n, []) end)

    restored = Tartarus.Host.call(host, :restore, 60_000)
    adopted = Tartarus.Host.call(host, :adopted, 60_000)

    Logger.warning(
      "host #{inspect(host)} restarted after a crash; agents adopted: #{inspect(adopted)}; " <>
        "restored (agents, in doubt): #{inspect(restored)}; failed plugins and links: " <>
        inspect(Enum.reject(plugins ++ links, &(&1 == :ok)), limit: 8)
    )

    {:noreply, state}
  end

  # The host is stopping (or its server restarting): the mark tells the host's server not to
  # take its agents' deaths for crashes (no restart, no removal: with persistence they are
  # restored when the host starts again) and refuses creates meanwhile. A restarted keeper
  # (init/1) or server takes it away.
  @impl true
  def terminate(_reason, %{host: host}) do
    case Tartarus.Host.local(host) do
      {:ok, info} -> Tartarus.Ledger.mark_stopping(info)
      _ -> :ok
    end
  end

  @impl true
  def handle_call(msg, from, state) do
    Tartarus.Events.drop(__MODULE__, :call, msg)
    Tartarus.Events.reply(from, {:error, :unexpected_call})
    {:noreply, state}
  end

  @impl true
  def handle_cast(msg, state) do
    Tartarus.Events.drop(__MODULE__, :cast, msg)
    {:noreply, state}
  end

  @impl true
  def handle_info(msg, state) do
    Tartarus.Events.drop(__MODULE__, :info, msg)
    {:noreply, state}
  end
end
