defmodule Tartarus.Host.Supervisor do
  @moduledoc false
  # One host's process tree. The server comes first because it owns the ledger and store
  # tables the agents and plugins use; the agents' and plugins' supervisors follow, so on
  # shutdown agents and plugins stop before their tables disappear. :one_for_all because
  # agents and plugins hold references to the server's tables: a restarted server means a
  # fresh host (persistence, when enabled, restores agents from disk).
  use Supervisor

  def start_link({name, opts}) do
    Supervisor.start_link(__MODULE__, {name, opts}, name: via(:host_sup, name))
  end

  def via(kind, name), do: {:via, Registry, {Tartarus.HostRegistry, {kind, name}}}

  @impl true
  def init({name, opts}) do
    children = [
      {Tartarus.Host.Server, {name, opts}},
      %{
        id: :agents,
        start:
          {DynamicSupervisor, :start_link, [[strategy: :one_for_one, name: via(:agents, name)]]},
        type: :supervisor
      },
      %{
        id: :plugins,
        start:
          {DynamicSupervisor, :start_link, [[strategy: :one_for_one, name: via(:plugins, name)]]},
        type: :supervisor
      }
    ]

    Supervisor.init(children, strategy: :one_for_all, max_restarts: 0)
  end
end
