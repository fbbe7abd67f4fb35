defmodule TartarusEmu.DashboardBrowserTest do
  # The dashboard in a real headless Chromium (Debian's `chromium`, driven over the DevTools
  # protocol by TartarusTools.Browser) against an emulated network of 4 hosts:
  # asserts on what the browser rendered. Excluded with `--exclude browser`; skipped with a
  # note when no Chromium is installed (scripts/test installs it and insists on it).
  use ExUnit.Case, async: false

  import TartarusEmu.EmuCase
  alias TartarusEmu.{Network, Topology}
  alias TartarusTools.Browser

  @moduletag :browser
  @moduletag timeout: 120_000
  @token "browser-test-token"
  @screenshot Path.expand("../../../../_build/dashboard/dashboard.png", __DIR__)

  setup do
    net = start_network!(Topology.grid(2, 2))
    h = fn n -> Network.host(net, n) end
    {:ok, a1} = Tartarus.create_mobile_agent(h.(:h1), Tartarus.Examples.Echo, nil, name: "scout")

    {:ok, a2} =
      Tartarus.create_mobile_agent(h.(:h4), Tartarus.Examples.Echo, nil, name: "courier")

    {:ok, dash} = TartarusEmu.Dashboard.start_link(net, token: @token, batch_ms: 100)
    {:ok, b} = Browser.start(width: 1400, height: 1000)
    on_exit(fn -> Browser.stop(b) end)
    :ok = Browser.open(b, TartarusDashboard.url(dash))
    :ok = Browser.wait(b, "document.body.dataset.ready === '1'", 15_000)
    %{net: net, b: b, a1: a1, a2: a2, h: h, dash: dash}
  end

  defp eval!(b, js) do
    {:ok, v} = Browser.eval(b, js)
    v
  end

  defp agent_host(b, id),
    do:
      eval!(
        b,
        "(document.querySelector('#overlay circle.agent[data-agent=\"#{id}\"]') || {dataset: {}}).dataset.host || null"
      )

  test "hosts, links and agents are drawn; a move shows up; no token, no action", c do
    %{b: b, a1: a1, a2: a2} = c

    # Hosts and links of the overlay, and each agent at its host, in the graph and the table.
    assert eval!(
             b,
             "[...document.querySelectorAll('#overlay g.host')].map(g => g.dataset.host).sort()"
           ) ==
             ["h1", "h2", "h3", "h4"]

    assert eval!(b, "document.querySelectorAll('#overlay line.link').length") == 4
    assert agent_host(b, a1) == "h1"
    assert agent_host(b, a2) == "h4"

    assert eval!(
             b,
             "document.querySelector('#agents tr[data-agent=\"#{a2}\"] td.where').textContent"
           ) == "h4"

    # The event stream connects on its own after the first data are drawn.
    :ok = Browser.wait(b, "document.getElementById('stream').textContent === 'live'", 15_000)

    # The agent moves (outside the page): the page shows it at its new host.
    :ok = Tartarus.move({a1, c.h.(:h1)}, c.h.(:h2))

    assert :ok =
             Browser.wait(
               b,
               "document.querySelector('#overlay circle.agent[data-agent=\"#{a1}\"][data-host=\"h2\"]')",
               5_000
             )

    # The arrival is in the Events tab's list (drawn when the tab is shown).
    eval!(b, ~s|document.querySelector('#tabs button[data-tab="events"]').click(); true|)

    assert :ok =
             Browser.wait(
               b,
               "[...document.querySelectorAll('#events div.arrival')].some(d => d.textContent.includes('#{a1}'))",
               5_000
             )

    eval!(b, ~s|document.querySelector('#tabs button[data-tab="overlay"]').click(); true|)

    # Without the token the page is read-only: a click on "kill" is refused, in plain words.
    assert eval!(b, "document.getElementById('mode').textContent") == "read-only"
    eval!(b, "document.querySelector('#agents tr[data-agent=\"#{a2}\"]').click(); true")
    :ok = Browser.wait(b, "document.querySelector('#detail button[data-action=kill]')", 5_000)
    eval!(b, "document.querySelector('#detail button[data-action=kill]').click(); true")

    :ok =
      Browser.wait(b, "document.getElementById('notice').textContent.includes('refused')", 5_000)

    notice = eval!(b, "document.getElementById('notice').textContent")
    assert notice =~ "kill refused"
    assert notice =~ "token"
    assert {:ok, _} = Tartarus.whereis({a2, c.h.(:h4)})
    assert agent_host(b, a2) == "h4"
  end

  test "with the token, the page breaks a link and moves an agent; the screenshot", c do
    %{b: b, a2: a2, net: net} = c

    eval!(
      b,
      "document.getElementById('token').value = '#{@token}'; document.getElementById('token-set').click(); true"
    )

    # The token is checked as it is entered.
    :ok = Browser.wait(b, "document.getElementById('mode').textContent === 'token ok'", 15_000)

    # Break h1-h2 from h1's detail panel.
    eval!(b, "document.querySelector('#hosts tr[data-host=\"h1\"]').click(); true")
    :ok = Browser.wait(b, "document.querySelector('#detail button[data-action=break]')", 5_000)

    eval!(
      b,
      "document.querySelector('#detail select').value = 'h2'; document.querySelector('#detail button[data-action=break]').click(); true"
    )

    :ok =
      Browser.wait(
        b,
        "document.getElementById('notice').textContent === 'break link: done'",
        5_000
      )

    refute Network.live?(net, :h1, :h2)

    :ok =
      Browser.wait(
        b,
        "document.querySelector('#overlay line.link.down[data-link=\"h1-h2\"]')",
        8_000
      )

    # Move an agent from its detail panel.
    eval!(b, "document.querySelector('#agents tr[data-agent=\"#{a2}\"]').click(); true")
    :ok = Browser.wait(b, "document.querySelector('#detail button[data-action=move]')", 5_000)

    eval!(
      b,
      "document.querySelector('#detail select').value = 'h3'; document.querySelector('#detail button[data-action=move]').click(); true"
    )

    :ok =
      Browser.wait(
        b,
        "document.querySelector('#overlay circle.agent[data-agent=\"#{a2}\"][data-host=\"h3\"]')",
        5_000
      )

    assert {:ok, h3} = Tartarus.whereis({a2, c.h.(:h4)})
    assert h3 == c.h.(:h3)

    # Let the agent's detail show its new host, then keep a picture of the page.
    eval!(b, "document.querySelector('#agents tr[data-agent=\"#{a2}\"]').click(); true")

    :ok =
      Browser.wait(
        b,
        "(document.getElementById('detail-host') || {}).textContent === 'h3'",
        5_000
      )

    assert :ok = Browser.screenshot(b, @screenshot)
    assert <<0x89, "PNG", _::binary>> = File.read!(@screenshot)
  end

  test "a building's floors are drawn side by side", %{b: b} do
    topo =
      Topology.new([:f1, :f2, :g1, :g2], [{:f1, :f2}, {:g1, :g2}, {:f1, :g1}],
        positions: %{f1: {0, 0, 0}, f2: {9, 0, 0}, g1: {0, 0, 4}, g2: {9, 0, 4}},
        floors: %{f1: 0, f2: 0, g1: 1, g2: 1}
      )

    net = start_network!(topo)
    {:ok, dash} = TartarusEmu.Dashboard.start_link(net)
    :ok = Browser.open(b, TartarusDashboard.url(dash))
    :ok = Browser.wait(b, "document.body.dataset.ready === '1'", 60_000)

    assert eval!(
             b,
             "[...document.querySelectorAll('#overlay rect[data-floor]')].map(r => r.dataset.floor)"
           ) ==
             ["0", "1"]

    # Hosts at the same x and y on two floors are not drawn on top of each other.
    x = fn h ->
      eval!(
        b,
        ~s|+document.querySelector('#overlay g.host[data-host="#{h}"]').getAttribute('transform').match(/\\(([\\d.]+)/)[1]|
      )
    end

    assert x.("f2") < x.("g1")
  end

  test "display: an agent's detail follows it, charts label their axes, equal series both show, one kept badge",
       c do
    %{b: b, a1: a1, dash: dash} = c

    # The detail of an agent says where it is now, not where it was when clicked.
    eval!(b, "document.querySelector('#agents tr[data-agent=\"#{a1}\"]').click(); true")
    :ok = Browser.wait(b, "document.getElementById('detail-host')?.textContent === 'h1'", 15_000)
    :ok = Tartarus.move({a1, c.h.(:h1)}, c.h.(:h2))
    :ok = Browser.wait(b, "document.getElementById('detail-host').textContent === 'h2'", 15_000)

    # Events per second: the value axis labelled at 0, half and the top, the time axis at
    # three places, outside the plot; arrivals and departures (equal here) both visible:
    # the later one dashed and thinner.
    eval!(b, ~s|document.querySelector('#tabs button[data-tab="events"]').click(); true|)

    :ok =
      Browser.wait(
        b,
        ~s|document.querySelector('#rates polyline[data-series="arrival"]') && document.querySelector('#rates polyline[data-series="departure"]')|,
        15_000
      )

    assert eval!(b, "[...document.querySelectorAll('#rates .plot .y')].length") == 3

    assert eval!(
             b,
             "[...document.querySelectorAll('#rates .plot .x span')].map(s => s.textContent).pop()"
           ) == "now"

    assert eval!(b, "document.querySelectorAll('#rates svg text').length") == 0

    [arr, dep] =
      for s <- ~w(arrival departure),
          do:
            eval!(
              b,
              ~s|(p => [p.getAttribute('stroke-width'), p.getAttribute('stroke-dasharray')])(document.querySelector('#rates polyline[data-series="#{s}"]'))|
            )

    assert [w_arr, nil] = arr
    assert [w_dep, dash_dep] = dep
    assert dash_dep != nil and String.to_float(w_dep) < String.to_float(w_arr)

    # The labels do not overlap the plot: they are left of its lines.
    assert eval!(
             b,
             "(() => { const y = document.querySelector('#rates .plot .y').getBoundingClientRect(), p = document.querySelector('#rates svg').getBoundingClientRect(); return y.right <= p.left; })()"
           )

    # A kept page: one badge says so.
    :ok = TartarusDashboard.keep(dash)
    :ok = Browser.wait(b, "!document.getElementById('kept').hidden", 15_000)

    assert eval!(
             b,
             "[...document.querySelectorAll('header .badge')].filter(e => !e.hidden && /run over/.test(e.textContent)).length"
           ) == 1

    assert eval!(b, "document.getElementById('stream').hidden")
  end
end
