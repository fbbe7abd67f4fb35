Code.require_file("support/peer_line.exs", __DIR__)

defmodule Tartarus.DashboardFleetBrowserTest do
  # The fleet seen from one node, in a real headless Chromium: three peer nodes, one host
  # each, linked in a line h1 (node a) - h2 (node b) - h3 (node c), so that c is reached from
  # a only through b. The dashboard runs on a. The page shows the other nodes' hosts, their
  # agents and their plugins' last readings; c's hosts arrive through b (a never connects to
  # c); with the token, the page moves an agent to h2 (on b) by its short name; the health
  # tab draws a's and c's charts. Screenshots of each view go to _build/dashboard/.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport

  alias TartarusTools.Browser
  alias Tartarus.JSON

  @moduletag :peer
  @moduletag :browser
  @moduletag timeout: 600_000
  @token "fleet-browser-token"
  @shots Path.expand("../_build/dashboard", __DIR__)

  setup do
    %{nodes: [a, b, c], hosts: [h1, h2, h3]} = Tartarus.PeerLine.start!("fleet")

    sensor = Tartarus.Plugin.SimSensor

    :ok =
      Tartarus.attach_plugin(
        h2,
        :thermo,
        {sensor, signal: [21.5, 22.0], unit: "C", capabilities: [:temperature]}
      )

    {:ok, 21.5} = :erpc.call(b, Tartarus, :read_plugin, [h2, :thermo])

    :ok =
      Tartarus.attach_plugin(
        h3,
        :lux,
        {sensor, signal: [300], unit: "lx", interval_ms: 200, capabilities: [:light]}
      )

    echo = Tartarus.Examples.Echo
    {:ok, scout} = :erpc.call(a, Tartarus, :create_mobile_agent, [h1, echo, nil, [name: "scout"]])

    {:ok, courier} =
      :erpc.call(c, Tartarus, :create_mobile_agent, [h3, echo, nil, [name: "courier"]])

    {:ok, dash} = :erpc.call(a, TartarusDashboard, :start, [[token: @token]])
    url = TartarusDashboard.url(dash)
    {:ok, br} = Browser.start(width: 1400, height: 1100)
    on_exit(fn -> Browser.stop(br) end)
    :ok = Browser.open(br, url)
    :ok = Browser.wait(br, "document.body.dataset.ready === '1'", 120_000)

    %{a: a, b: b, c: c, h1: h1, h2: h2, h3: h3, scout: scout, courier: courier, b_: br, url: url}
  end

  defp eval!(b, js) do
    {:ok, v} = Browser.eval(b, js)
    v
  end

  defp wait!(b, js, ms \\ 60_000), do: assert(:ok = Browser.wait(b, js, ms))

  test "one node's page shows the fleet, moves an agent to a remote host by its short name, draws health",
       ctx do
    %{b_: b, a: a, b: nb, c: nc, scout: scout, courier: courier} = ctx
    File.mkdir_p!(@shots)

    # Every node's hosts, each marked with its node; the links across nodes.
    wait!(b, "document.querySelectorAll('#overlay g.host').length === 3")

    assert eval!(
             b,
             "[...document.querySelectorAll('#overlay g.host')].map(g => [g.dataset.host, g.dataset.node]).sort()"
           ) == [["h1", "#{a}"], ["h2", "#{nb}"], ["h3", "#{nc}"]]

    wait!(b, "document.querySelectorAll('#overlay line.link.cross').length === 2")
    assert eval!(b, "document.getElementById('graph-title').textContent") =~ "3 hosts on 3 nodes"

    # The other nodes' agents, and the plugins with their capabilities and last readings.
    wait!(b, ~s|document.querySelector('#agents tr[data-agent="#{courier}"]')|)

    assert eval!(
             b,
             ~s|[...document.querySelectorAll('#agents tr[data-agent="#{courier}"] td')].map(td => td.textContent)|
           ) == [courier, "courier", "Tartarus.Examples.Echo", "h3", "#{nc}"]

    assert eval!(
             b,
             ~s|document.querySelector('#hosts tr[data-host="h2"] td.plugins').textContent|
           ) ==
             "thermo [temperature] = 21.5"

    wait!(
      b,
      ~s|document.querySelector('#hosts tr[data-host="h3"] td.plugins').textContent === 'lux [light] = {:reading, 300}'|
    )

    assert eval!(b, ~s|document.querySelector('#hosts tr[data-host="h3"] td.age').textContent|) =~
             ~r/now|s ago/

    # The nodes, c reached through b; a never connected to c to read it.
    wait!(b, "document.querySelectorAll('#nodes tbody tr').length === 3")

    assert eval!(b, ~s|document.querySelector('#nodes tr[data-node="#{nc}"] td').textContent|) =~
             "via"

    refute nc in :erpc.call(a, Node, :list, [])

    {:ok, 200, body} = TartarusDashboard.http_get(ctx.url <> "api/fleet")
    fleet = JSON.decode!(body)

    assert Enum.find(fleet["nodes"], &(&1["node"] == "#{nc}"))["path"] == [
             "#{a}",
             "#{nb}",
             "#{nc}"
           ]

    assert :ok = Browser.screenshot(b, Path.join(@shots, "fleet_overlay.png"))

    # With the token: move the scout (on a) to h2 (on b), named by its short name.
    eval!(
      b,
      "document.getElementById('token').value = '#{@token}'; document.getElementById('token-set').click(); true"
    )

    eval!(b, ~s|document.querySelector('#agents tr[data-agent="#{scout}"]').click(); true|)
    wait!(b, "document.querySelector('#detail button[data-action=move]')")

    eval!(
      b,
      "document.querySelector('#detail select').value = 'h2'; document.querySelector('#detail button[data-action=move]').click(); true"
    )

    wait!(b, "document.getElementById('notice').textContent === 'move: done'")
    assert :erpc.call(a, Tartarus, :whereis, [scout]) == {:ok, ctx.h2}

    wait!(
      b,
      ~s|document.querySelector('#overlay circle.agent[data-agent="#{scout}"][data-host="h2"]')|
    )

    # Health: this node's charts, then c's (read through b).
    eval!(b, ~s|document.querySelector('#tabs button[data-tab="health"]').click(); true|)
    wait!(b, ~s|document.querySelector('#charts .chart[data-chart="memory"] polyline')|)

    for chart <- ~w(memory processes run_queue sched_util mailbox hop arrivals) do
      assert eval!(b, ~s|!!document.querySelector('#charts .chart[data-chart="#{chart}"]')|),
             chart
    end

    eval!(
      b,
      ~s|const s = document.getElementById('health-node'); s.value = '#{nc}'; s.dispatchEvent(new Event('change')); true|
    )

    wait!(b, ~s|document.getElementById('health-note').textContent.includes('#{nc}')|)
    wait!(b, ~s|document.querySelector('#charts .chart[data-chart="memory"] polyline')|)
    # Two or more samples of c: a line to look at.
    eventually(
      fn ->
        eval!(b, "drawHealth().then(() => true)") &&
          eval!(b, "document.getElementById('health-note').textContent") =~
            ~r/^([2-9]|\d\d+) samples/
      end,
      60_000
    )

    assert :ok = Browser.screenshot(b, Path.join(@shots, "fleet_health.png"))

    # Events: the rate chart and the sampled list.
    eval!(b, ~s|document.querySelector('#tabs button[data-tab="events"]').click(); true|)
    wait!(b, ~s|document.querySelector('#rates svg')|)
    assert eval!(b, "document.getElementById('ev-dropped').textContent") =~ "showing"
    assert :ok = Browser.screenshot(b, Path.join(@shots, "fleet_events.png"))
  end
end
