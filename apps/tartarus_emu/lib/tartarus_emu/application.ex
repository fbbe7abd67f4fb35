defmodule TartarusEmu.Application do
  @moduledoc false
  # Its one job: the networks' tags (TartarusEmu.Network), a counter of this VM, so that
  # the n-th network of a run has the same host names on every run. It supervises nothing.

  use Application

  @impl true
  def start(_type, _args) do
    :persistent_term.put({TartarusEmu.Network, :tags}, :atomics.new(1, signed: false))
    Supervisor.start_link([], strategy: :one_for_one, name: TartarusEmu.Supervisor)
  end
end
