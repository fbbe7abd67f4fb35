Code.require_file("support/peer_line.exs", __DIR__)

defmodule Tartarus.DashboardPagesBrowserTest do
  # The dashboard's addresses and pages in a real headless Chromium, over three peer nodes
  # (hosts h1 on a, h2 on b, h3 on c, linked in a line; the dashboard on a): an agent's
  # address opened directly shows its page, a host's address its page (and reload and back
  # keep the address); the processes view lists a node's top processes; a `{:ping, 1}`
  # typed as Elixir text and requested of an Echo shows its reply; the sequence view draws a
  # message one agent sent another; the token is checked when entered. Screenshots of the
  # agent page, the sequence view and the processes view go to _build/dashboard/.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport

  alias TartarusTools.Browser

  @moduletag :peer
  @moduletag :browser
  @moduletag :dashboard_pages
  @moduletag timeout: 600_000
  @token "pages-browser-token"
  @shots Path.expand("../_build/dashboard", __DIR__)

  setup do
    %{nodes: [a, b, c], hosts: [h1, _h2, h3]} = Tartarus.PeerLine.start!("pages")

    echo = Tartarus.Examples.Echo
    {:ok, alpha} = :erpc.call(a, Tartarus, :create_mobile_agent, [h1, echo, nil, [name: "alpha"]])
    {:ok, beta} = :erpc.call(a, Tartarus, :create_mobile_agent, [h1, echo, nil, [name: "beta"]])

    {:ok, courier} =
      :erpc.call(c, Tartarus, :create_mobile_agent, [h3, echo, nil, [name: "courier"]])

    {:ok, dash} = :erpc.call(a, TartarusDashboard, :start, [[token: @token]])
    url = TartarusDashboard.url(dash)
    {:ok, br} = Browser.start(width: 1400, height: 1100)
    on_exit(fn -> Browser.stop(br) end)

    %{a: a, b: b, c: c, h1: h1, alpha: alpha, beta: beta, courier: courier, br: br, url: url}
  end

  defp eval!(b, js) do
    {:ok, v} = Browser.eval(b, js)
    v
  end

  # On a time-out, what the page says (the notice, the reply box, the address).
  defp wait!(b, js, ms \\ 60_000) do
    case Browser.wait(b, js, ms) do
      :ok ->
        :ok

      other ->
        flunk(
          "#{inspect(other)} waiting for #{js}; the page: " <>
            inspect(
              eval!(
                b,
                "[location.hash, document.getElementById('notice').textContent, (document.getElementById('page-reply') || {}).textContent]"
              )
            )
        )
    end
  end

  defp open!(b, url) do
    :ok = Browser.open(b, url)
    wait!(b, "document.body.dataset.ready === '1'", 120_000)
  end

  defp text(b, selector),
    do: eval!(b, "(document.querySelector(#{inspect(selector)}) || {}).textContent || null")

  test "addresses of agents, hosts and tabs; processes; a request's reply; a sequence", ctx do
    %{br: b, url: url, a: a, b: nb, alpha: alpha, beta: beta, courier: courier} = ctx
    File.mkdir_p!(@shots)

    # An agent of another node (c), opened at its address in a fresh tab: its page.
    open!(b, url <> "#/agents/#{courier}")
    wait!(b, ~s|document.querySelector('#page[data-page="agent"] #page-summary')|)
    assert text(b, "#page-title") =~ "agent #{courier} courier (Tartarus.Examples.Echo)"
    assert text(b, ~s|#page-summary tr[data-field="host"] td:last-child|) == "h3"

    assert eval!(
             b,
             ~s|document.querySelector('#tabs button[data-tab="page"]').classList.contains('on')|
           )

    # A host of another node (b), at its address; a reload keeps it; back returns to the agent.
    eval!(b, ~s|location.hash = '#/hosts/h2'; true|)
    wait!(b, ~s|document.querySelector('#page[data-page="host"][data-id="h2"] #page-summary')|)
    assert text(b, ~s|#page-summary tr[data-field="node"] td:last-child|) == "#{nb}"
    eval!(b, "location.reload(); true")
    Process.sleep(200)
    wait!(b, "document.body.dataset.ready === '1'", 120_000)
    wait!(b, ~s|document.querySelector('#page[data-page="host"][data-id="h2"] #page-summary')|)
    eval!(b, "history.back(); true")
    wait!(b, ~s|document.querySelector('#page[data-page="agent"][data-id="#{courier}"]')|)

    # A tab's address: the events tab, and back to the host.
    eval!(b, ~s|document.querySelector('#tabs button[data-tab="events"]').click(); true|)

    wait!(
      b,
      "location.hash === '#/events' && document.getElementById('tab-events').classList.contains('on')"
    )

    # The token is checked when entered: a wrong one says so at once, the right one is ok.
    eval!(
      b,
      "document.getElementById('token').value = 'not-the-token'; document.getElementById('token-set').click(); true"
    )

    wait!(b, "document.getElementById('mode').textContent === 'token wrong'")

    eval!(
      b,
      "document.getElementById('token').value = '#{@token}'; document.getElementById('token-set').click(); true"
    )

    wait!(b, "document.getElementById('mode').textContent === 'token ok'")

    # {:ping, 1} typed as Elixir text, requested of alpha (an Echo): its reply is shown.
    eval!(b, ~s|location.hash = '#/agents/#{alpha}'; true|)
    wait!(b, ~s|document.querySelector('#page[data-id="#{alpha}"] #page-term')|)

    eval!(
      b,
      ~s|document.getElementById('page-term').value = '{:ping, 1}'; document.querySelector('#page button[data-action="request"]').click(); true|
    )

    wait!(b, "!document.getElementById('page-reply').hidden")
    assert text(b, "#page-reply") == "reply to {:ping, 1}: {:pong, 1}"

    # Text that is not a literal is refused, never run.
    eval!(
      b,
      ~s|document.getElementById('page-term').value = 'exit(:normal)'; document.querySelector('#page button[data-action="request"]').click(); true|
    )

    wait!(b, "document.getElementById('page-reply').textContent.includes('not a literal')")
    assert text(b, "#page-reply") =~ "request refused: not a literal term: exit(:normal) (a call"
    assert a in Node.list()

    # alpha tells beta {:ping, 2}: a message from one agent to another.
    eval!(
      b,
      ~s|document.getElementById('page-reply').textContent = ''; document.getElementById('page-term').value = '{:tell, "#{beta}", {:ping, 2}}'; document.querySelector('#page button[data-action="post"]').click(); true|
    )

    wait!(
      b,
      "document.getElementById('page-reply').textContent.startsWith('posted') || document.getElementById('page-reply').textContent.includes('post refused')"
    )

    assert text(b, "#page-reply") =~ "posted {:tell", text(b, "#notice")

    eventually(fn ->
      {:ok, 200, body} =
        TartarusDashboard.http_get(url <> "api/events?type=message&agent=#{beta}")

      Enum.any?(
        Tartarus.JSON.decode!(body)["events"],
        &(&1["sender"] == alpha and &1["message"] == "{:ping, 2}")
      )
    end)

    # alpha's page lists the message it sent, and the one it received from outside.
    eval!(b, "drawPage(false).then(() => true)")

    wait!(
      b,
      ~s|document.querySelector('#page-messages-table tr.sent a[data-agent-link="#{beta}"]')|
    )

    assert text(b, "#page-messages-table tr.sent td:nth-child(5)") == "{:ping, 2}"
    assert :ok = Browser.screenshot(b, Path.join(@shots, "agent_page.png"))

    # The sequence of the messages between alpha and beta, at its address.
    eval!(b, ~s|location.hash = '#/sequence/#{alpha},#{beta}'; true|)
    wait!(b, ~s|document.querySelector('#seq g.msg[data-from="#{alpha}"][data-to="#{beta}"]')|)

    assert text(b, ~s|#seq g.msg[data-from="#{alpha}"][data-to="#{beta}"] text|) =~
             "post {:ping, 2}"

    assert eval!(
             b,
             "[...document.querySelectorAll('#seq [data-lifeline]')].map(t => t.dataset.lifeline)"
           ) ==
             [alpha, beta, "outside"]

    assert eval!(
             b,
             ~s|document.querySelector('#seq g.msg[data-from="outside"][data-to="#{alpha}"]') !== null|
           )

    assert :ok = Browser.screenshot(b, Path.join(@shots, "sequence.png"))

    # The processes view of node b (read through the fleet's path), by memory.
    eval!(b, ~s|location.hash = '#/processes/#{nb}'; true|)

    wait!(
      b,
      ~s|document.getElementById('procs').dataset.node === '#{nb}' && document.querySelectorAll('#procs tbody tr').length === 20|
    )

    mem =
      eval!(
        b,
        "[...document.querySelectorAll('#procs tbody tr td:nth-child(4)')].map(td => parseFloat(td.textContent))"
      )

    assert mem == Enum.sort(mem, :desc)
    assert text(b, "#proc-note") =~ ~r/the top 20 of \d+ processes of #{nb} by memory/

    # a's processes include its agents, named.
    eval!(b, ~s|location.hash = '#/processes/#{a}'; true|)

    eval!(
      b,
      ~s|const s = document.getElementById('proc-sort'); s.value = 'mailbox'; s.dispatchEvent(new Event('change')); true|
    )

    wait!(
      b,
      ~s|document.getElementById('procs').dataset.node === '#{a}' && document.getElementById('proc-note').textContent.includes('by mailbox')|
    )

    eval!(
      b,
      ~s|document.getElementById('proc-sort').value = 'memory'; location.hash = '#/processes/#{nb}'; true|
    )

    wait!(
      b,
      ~s|document.getElementById('procs').dataset.node === '#{nb}' && document.getElementById('proc-note').textContent.includes('by memory')|
    )

    assert :ok = Browser.screenshot(b, Path.join(@shots, "processes.png"))

    # At 1,400 px the agents table does not scroll sideways (its node column is seen).
    eval!(b, ~s|location.hash = '#/overlay'; true|)
    wait!(b, ~s|document.querySelector('#agents tr[data-agent="#{courier}"]')|)

    assert eval!(
             b,
             "(() => { const s = document.getElementById('agents').closest('section'); return s.scrollWidth <= s.clientWidth; })()"
           )
  end
end
