defmodule Tartarus.Application do
  @moduledoc false
  use Application

  # Node-level services first (registries, events, code cache, host directory), then the
  # supervisor of hosts, so hosts can rely on every service when they start and are shut
  # down before the services they use.
  @impl true
  def start(_type, _args) do
    Tartarus.Events.setup()

    children = [
      {Registry, keys: :unique, name: Tartarus.HostRegistry},
      Tartarus.AgentTable,
      {Registry, keys: :duplicate, name: Tartarus.Events.Registry},
      Tartarus.CodeCache,
      Tartarus.Host.Directory,
      Tartarus.Overlay,
      {DynamicSupervisor, name: Tartarus.Hosts, strategy: :one_for_one}
    ]

    Supervisor.start_link(children, strategy: :rest_for_one, name: Tartarus.Supervisor)
  end
end
