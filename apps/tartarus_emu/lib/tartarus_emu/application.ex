defmodule TartarusEmu.Application do
  # See https://hexdocs.pm/elixir/Application.html
  # for more information on OTP Applications
  @moduledoc false

  use Application

  @impl true
  def start(_type, _args) do
    # The networks' tags (TartarusEmu.Network): a counter of this VM, so that the n-th
    # network of a run has the same host names on every run.
    :persistent_term.put({TartarusEmu.Network, :tags}, :atomics.new(1, signed: false))

    children = [
      # Starts a worker by calling: TartarusEmu.Worker.start_link(arg)
      # {TartarusEmu.Worker, arg}
    ]

    # See https://hexdocs.pm/elixir/Supervisor.html
    # for other strategies and supported options
    opts = [strategy: :one_for_one, name: TartarusEmu.Supervisor]
    Supervisor.start_link(children, opts)
  end
end
