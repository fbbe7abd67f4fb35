defmodule TartarusEmu.DashboardBrowserBigTest do
  # Too many hosts to draw: with 500 emulated hosts the page draws groups of hosts instead
  # of the graph, and the API's summary holds those groups. (10,000 hosts are measured by
  # `mix tartarus.dashboard.bench`, not tested: the network alone takes over a minute.)
  use ExUnit.Case, async: false

  import TartarusEmu.EmuCase
  alias TartarusEmu.{Network, Topology}
  alias TartarusTools.Browser

  @moduletag :browser
  @moduletag timeout: 180_000

  test "500 hosts: the page aggregates; the summary has 100 groups covering every host" do
    net = start_network!(Topology.grid(20, 25))

    for n <- Enum.take_every(net.topology.nodes, 25) do
      {:ok, _} = Tartarus.create_mobile_agent(Network.host(net, n), Tartarus.Examples.Echo, nil)
    end

    :ok = Network.isolate(net, :h7)
    {:ok, dash} = TartarusEmu.Dashboard.start_link(net)
    url = TartarusDashboard.url(dash)

    {:ok, 200, body} = TartarusDashboard.http_get(url <> "api/summary")
    summary = Tartarus.JSON.decode!(body)
    assert summary["hosts"] == 500 and summary["hosts_down"] == 1
    assert length(summary["buckets"]) == 100
    assert Enum.sum(Enum.map(summary["buckets"], & &1["hosts"])) == 500
    assert Enum.sum(Enum.map(summary["buckets"], & &1["residents"])) == 20

    assert [%{"first" => "h6", "last" => "h10", "down" => 1}] =
             Enum.filter(summary["buckets"], &(&1["down"] > 0))

    {:ok, b} = Browser.start()
    on_exit(fn -> Browser.stop(b) end)
    :ok = Browser.open(b, url)
    :ok = Browser.wait(b, "document.body.dataset.ready === '1'", 60_000)

    {:ok, seen} =
      Browser.eval(b, """
      ({overlay: !!document.getElementById('overlay'),
        groups: document.querySelectorAll('#aggregate rect.bucket').length,
        down: [...document.querySelectorAll('#aggregate rect.bucket')].filter(r => r.getAttribute('fill').startsWith('rgb(255')).map(r => r.dataset.bucket),
        title: document.getElementById('graph-title').textContent,
        host_rows: document.querySelectorAll('#hosts tbody tr').length,
        agent_rows: document.querySelectorAll('#agents tbody tr').length})
      """)

    assert seen["overlay"] == false
    assert seen["groups"] == 100
    assert seen["down"] == ["h6..h10"]
    assert seen["title"] == "Overlay: 500 hosts (aggregated)"
    assert seen["host_rows"] == 50
    assert seen["agent_rows"] == 20
  end
end
