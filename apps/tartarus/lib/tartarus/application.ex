defmodule Tartarus.Application do
  @moduledoc false
  use Application

  # The supervision tree, chosen so that no single failure of a node-level service takes a
  # host down:
  #
  #   (top, unnamed)                      :one_for_one
  #   ├── services (unnamed)              :one_for_one, max 10 restarts per second
  #   │   ├── Tartarus.Events.Registry    subscriptions (name hidden, see below)
  #   │   ├── Tartarus.AgentTable         (its ETS table belongs to the application process)
  #   │   ├── Tartarus.CodeCache          (its ETS table belongs to the application process)
  #   │   ├── Tartarus.Host.Directory     (its table is a cache of remote host pids)
  #   │   ├── Tartarus.Overlay            the overlay's door (:tartarus_overlay)
  #   │   └── Tartarus.Host.ArrivalDoor   arriving agents' door (:tartarus_arrivals)
  #   └── host tree (unnamed)             :rest_for_one
  #       ├── Tartarus.HostRegistry       every host's and agent supervisor's name
  #       └── hosts (DynamicSupervisor)   one Tartarus.Host.Supervisor per host
  #
  # * Services restart one by one and never touch the hosts: the tables hosts and agents write
  #   (agent table, code cache) are created here, in the application's own process, so they
  #   outlive any service's restart; the directory's table is a cache that refills itself.
  #   Even if the services' supervisor gave up, the top supervisor restarts it alone.
  # * The host registry comes before the hosts' supervisor under :rest_for_one: a registry
  #   that restarted has forgotten every host's name, so the hosts restart with it (each host
  #   restores its agents when it has persistence, see Tartarus.Host.Supervisor). Nothing
  #   else restarts the hosts.
  # * Shutdown runs in reverse: hosts (and their agents) stop before the registry and the
  #   services they use.
  #
  # Junk messages: our own services (AgentTable, CodeCache, Directory) drop and count what they
  # do not expect (Tartarus.Events.drop/3). OTP's supervisors and Elixir's Registry processes
  # crash on an unexpected call or cast, and we cannot change their code, so no process of
  # theirs keeps a registered name another node could address: the supervisors here are
  # unnamed, the hosts' DynamicSupervisor is found through hosts/0, and the two registries'
  # processes are unregistered right after they start (Registry finds its partitions through
  # its ETS table, never by process name). Their pids are not secret, though: a connected node
  # that guesses one can still crash them (see the README on what only TLS can decide).
  @impl true
  def start(_type, _args) do
    Tartarus.Events.setup()
    Tartarus.AgentTable.setup()
    Tartarus.CodeCache.setup()
    # An agent's crash is logged once, by its host (Tartarus.Host.Agents).
    filter = {&Tartarus.Host.Agents.drop_agent_report/2, nil}
    _ = :logger.add_primary_filter(:tartarus_agent_crash_reports, filter)

    services = [
      registry(keys: :duplicate, name: Tartarus.Events.Registry),
      Tartarus.AgentTable,
      Tartarus.CodeCache,
      Tartarus.Host.Directory,
      Tartarus.Overlay,
      Tartarus.Host.ArrivalDoor
    ]

    host_tree = [
      registry(keys: :unique, name: Tartarus.HostRegistry),
      %{id: :hosts, start: {__MODULE__, :start_hosts, []}, type: :supervisor}
    ]

    children = [
      supervisor(:services, services, strategy: :one_for_one, max_restarts: 10, max_seconds: 1),
      supervisor(:host_tree, host_tree, strategy: :rest_for_one)
    ]

    Supervisor.start_link(children, strategy: :one_for_one)
  end

  @doc false
  # The DynamicSupervisor of the hosts (unnamed: see the note above).
  @spec hosts() :: pid()
  def hosts, do: :persistent_term.get({__MODULE__, :hosts})

  @doc false
  def start_hosts do
    with {:ok, pid} <- DynamicSupervisor.start_link(strategy: :one_for_one) do
      :persistent_term.put({__MODULE__, :hosts}, pid)
      {:ok, pid}
    end
  end

  @doc false
  # Starts a Registry and unregisters the names of its processes (its supervisor and
  # partitions): they crash on unexpected calls and casts, so nobody should reach them by name.
  def start_registry(opts) do
    with {:ok, pid} <- Registry.start_link(opts) do
      for {_, child, _, _} <- Supervisor.which_children(pid), is_pid(child), do: unregister(child)
      unregister(pid)
      {:ok, pid}
    end
  end

  defp unregister(pid) do
    case Process.info(pid, :registered_name) do
      {:registered_name, name} when is_atom(name) -> Process.unregister(name)
      _ -> true
    end
  end

  defp registry(opts) do
    %{id: opts[:name], start: {__MODULE__, :start_registry, [opts]}, type: :supervisor}
  end

  defp supervisor(id, children, opts) do
    %{id: id, start: {Supervisor, :start_link, [children, opts]}, type: :supervisor}
  end
end
