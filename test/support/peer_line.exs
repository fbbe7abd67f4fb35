defmodule Tartarus.PeerLine do
  @moduledoc """
  Three peer nodes a, b, c (sorted), one host each (h1 on a, h2 on b, h3 on c), linked in a
  line h1 - h2 - h3, so that c is reached from a only through b; the peers are stopped when
  the test ends (and are no longer connected). For the browser tests of the dashboard.
  """
  import ExUnit.Assertions

  @doc "Starts the line (peer names from `prefix`); returns `%{nodes: [a, b, c], hosts: [h1, h2, h3]}`."
  def start!(prefix) do
    {:ok, peers} = TartarusTools.Peer.start_many(prefix, 3)
    [a, b, c] = nodes = peers |> Enum.map(&elem(&1, 1)) |> Enum.sort()

    ExUnit.Callbacks.on_exit(fn ->
      Enum.each(peers, fn {pid, _} -> TartarusTools.Peer.stop(pid) end)
      for n <- nodes, do: refute(n in Node.list())
    end)

    {:ok, h1} = :erpc.call(a, Tartarus, :start_host, [:h1])
    {:ok, h2} = :erpc.call(b, Tartarus, :start_host, [:h2])
    {:ok, h3} = :erpc.call(c, Tartarus, :start_host, [:h3])
    :ok = Tartarus.connect(h1, h2)
    :ok = Tartarus.connect(h2, h3)
    %{nodes: nodes, hosts: [h1, h2, h3]}
  end
end
