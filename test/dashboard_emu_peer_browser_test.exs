defmodule Tartarus.DashboardEmuPeerBrowserTest do
  # An emulation over peer nodes (what `mix tartarus.emu --mode peer --dashboard PORT`
  # starts): 3 hosts on 3 peer BEAM nodes, the dashboard on this node (the controller, which
  # runs no host). In a real headless Chromium the page lists every node with its health,
  # `/api/info` says the fleet is shown, the Health tab draws a peer's charts and names its
  # host as the overlay does (`h2`, not the emulation's internal host name).
  use ExUnit.Case, async: false

  alias TartarusEmu.{Network, Topology}
  alias TartarusTools.Browser

  @moduletag :peer
  @moduletag :browser
  @moduletag :dashboard_emu_peer
  @moduletag timeout: 600_000

  setup do
    {:ok, net} = Network.start(Topology.line(3), mode: :peer)
    on_exit(fn -> Network.stop(net) end)
    {:ok, _} = Tartarus.create_mobile_agent(Network.host(net, :h1), Tartarus.Examples.Echo, nil)
    {:ok, dash} = TartarusEmu.Dashboard.start(net, [])
    on_exit(fn -> Process.exit(dash, :shutdown) end)
    {:ok, b} = Browser.start(width: 1400, height: 1100)
    on_exit(fn -> Browser.stop(b) end)
    :ok = Browser.open(b, TartarusDashboard.url(dash))
    :ok = Browser.wait(b, "document.body.dataset.ready === '1'", 120_000)
    %{net: net, b: b, url: TartarusDashboard.url(dash)}
  end

  defp eval!(b, js) do
    {:ok, v} = Browser.eval(b, js)
    v
  end

  defp wait!(b, js, ms \\ 60_000), do: assert(:ok = Browser.wait(b, js, ms))

  test "every node of a peer-mode emulation is listed with its health", %{
    net: net,
    b: b,
    url: url
  } do
    peers = net.nodes |> Enum.uniq() |> Enum.map(&to_string/1)
    assert length(peers) == 3
    all = Enum.sort([to_string(node()) | peers])

    {:ok, 200, body} = TartarusDashboard.http_get(url <> "api/info")
    assert Tartarus.JSON.decode!(body)["fleet"] == true

    assert eval!(b, "document.getElementById('graph-title').textContent") =~ "3 hosts on 3 nodes"

    # Every node in the nodes table, each peer with its host and a health reading.
    wait!(b, "document.querySelectorAll('#nodes tbody tr').length === 4")

    assert eval!(
             b,
             "[...document.querySelectorAll('#nodes tbody tr')].map(r => r.dataset.node).sort()"
           ) == all

    for {p, h} <-
          Enum.zip(Enum.map(~w(h1 h2 h3)a, &to_string(Network.beam_node(net, &1))), ~w(h1 h2 h3)) do
      wait!(
        b,
        ~s|(() => { const c = document.querySelectorAll('#nodes tr[data-node="#{p}"] td'); return c.length > 4 && c[1].textContent === '#{h}' && parseFloat(c[4].textContent) > 0; })()|
      )
    end

    # The Health tab: a peer's charts, its host named as on the overlay.
    p2 = to_string(Network.beam_node(net, :h2))
    eval!(b, ~s|location.hash = '#/health/#{p2}'; true|)
    wait!(b, ~s|document.getElementById('health-note').textContent.includes('#{p2}')|)
    wait!(b, ~s|document.querySelector('#charts .chart[data-chart="memory"] polyline')|)
    wait!(b, ~s|[...document.getElementById('health-host').options].some(o => o.value === 'h2')|)

    assert eval!(b, "[...document.getElementById('health-host').options].map(o => o.value)") ==
             ["", "h2"]

    # A host's series by its id.
    eval!(
      b,
      ~s|const s = document.getElementById('health-host'); s.value = 'h2'; s.dispatchEvent(new Event('change')); true|
    )

    wait!(b, ~s|document.querySelector('#charts .chart[data-chart="residents"]')|)
  end
end
