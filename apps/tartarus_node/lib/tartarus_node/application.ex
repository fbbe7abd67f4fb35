defmodule TartarusNode.Application do
  @moduledoc """
  Starts `TartarusNode.Boot` when the node was configured from its file (the release's
  `config/runtime.exs` puts the checked configuration in `:tartarus_node, :config`); starts
  nothing otherwise (in tests and `mix` tasks).
  """
  use Application

  @impl true
  def start(_type, _args) do
    children =
      case Application.get_env(:tartarus_node, :config) do
        nil -> []
        config -> [{TartarusNode.Boot, config}]
      end

    Supervisor.start_link(children, strategy: :one_for_one, name: TartarusNode.Supervisor)
  end
end
