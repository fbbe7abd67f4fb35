defmodule TartarusEmu.EmuCase do
  @moduledoc false
  # Helpers shared by the runtime tests: start a network that is stopped after the test,
  # and check that nothing leaks.
  import ExUnit.Callbacks, only: [on_exit: 1]

  def start_network!(topo, opts \\ []) do
    {:ok, net} = TartarusEmu.Network.start(topo, opts)
    on_exit(fn -> TartarusEmu.Network.stop(net) end)
    net
  end

  def neighbour_nodes(net, n) do
    net
    |> TartarusEmu.Network.host(n)
    |> Tartarus.neighbours()
    |> Enum.map(&TartarusEmu.Network.topo_node(net, &1))
    |> Enum.sort()
  end
end
