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

  def wait_until(fun, timeout \\ 5_000) do
    deadline = System.monotonic_time(:millisecond) + timeout
    do_wait(fun, deadline)
  end

  defp do_wait(fun, deadline) do
    cond do
      fun.() ->
        :ok

      System.monotonic_time(:millisecond) > deadline ->
        raise "condition not met in time"

      true ->
        Process.sleep(10)
        do_wait(fun, deadline)
    end
  end
end
