defmodule TartarusFirmware.Application do
  @moduledoc false
  # Boot: distribution first (so the host's address carries the node's final name), then
  # the host with its devices. A host that cannot start (a device refused by its plugin's
  # init) is logged and retried by the supervisor of TartarusFirmware.Node.
  use Application

  @impl true
  def start(_type, _args) do
    children = [TartarusFirmware.Distribution, TartarusFirmware.Node]
    Supervisor.start_link(children, strategy: :rest_for_one, name: TartarusFirmware.Supervisor)
  end
end
