defmodule TartarusEmu.DashboardPeerTest do
  # The dashboard of an emulation in :peer mode: hosts on three BEAM nodes, shown with the
  # node each lives on; events that happen on the peers reach the page's feed (through a
  # relay on each peer) and name hosts by their topology names.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport

  alias TartarusEmu.{Network, Topology}
  alias Tartarus.JSON

  @moduletag :peer
  @moduletag timeout: 300_000

  defp get(url, path) do
    {:ok, 200, body} = TartarusDashboard.http_get(url <> path)
    JSON.decode!(body)
  end

  test "hosts on their own BEAM nodes; a move between peers shows in the events" do
    {:ok, net} = Network.start(Topology.line(3), mode: :peer)

    try do
      {:ok, dash} = TartarusEmu.Dashboard.start_link(net)
      url = TartarusDashboard.url(dash)

      %{"hosts" => hosts} = get(url, "api/hosts")
      assert Enum.map(hosts, & &1["id"]) == ~w(h1 h2 h3)
      nodes = Enum.map(hosts, & &1["node"])
      assert length(Enum.uniq(nodes)) == 3
      refute to_string(node()) in nodes

      h = &Network.host(net, &1)
      {:ok, id} = Tartarus.create_mobile_agent(h.(:h1), Tartarus.Examples.Echo, nil)
      :ok = Tartarus.move({id, h.(:h1)}, h.(:h2))

      arrived = fn ->
        events = get(url, "api/events?type=arrival&agent=#{id}")["events"]
        events != [] && events
      end

      assert [%{"host" => "h2", "from" => "h1"}] = eventually(arrived, 10_000)

      assert %{"agents" => [%{"id" => ^id, "host" => "h2"}]} = get(url, "api/agents?host=h2")
      TartarusDashboard.stop(dash)
    after
      Network.stop(net)
    end
  end
end
