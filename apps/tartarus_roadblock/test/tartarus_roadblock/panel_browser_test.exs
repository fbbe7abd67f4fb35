defmodule TartarusRoadblock.PanelBrowserTest do
  # The administrator in a real headless Chromium (TartarusTools.Browser): the
  # roadblock panel shows the webcam snapshot as a picture the browser decoded and, while
  # the run waits, a button; a click on it (after the token is set on the page) releases
  # the rescue agent, and the run ends with the block rescued. Then a screenshot.
  use ExUnit.Case, async: false

  alias TartarusTools.Browser

  @moduletag :browser
  @moduletag timeout: 180_000
  @token "roadblock-browser-token"
  @screenshot Path.expand("../../../../_build/dashboard/roadblock_panel.png", __DIR__)

  test "the page shows the snapshot, and its button releases the rescue agent" do
    {:ok, l} = :gen_tcp.listen(0, [])
    {:ok, port} = :inet.port(l)
    :gen_tcp.close(l)

    {:ok, _} =
      TartarusRoadblock.start(seed: 2, out: false, dashboard: [port: port, token: @token])

    {:ok, b} = Browser.start(width: 1400, height: 1400)
    on_exit(fn -> Browser.stop(b) end)
    :ok = Browser.open(b, "http://127.0.0.1:#{port}/")
    :ok = Browser.wait(b, "document.body.dataset.ready === '1'", 15_000)

    # The panel offers its button once Santa is blocked (the page refreshes panels every 3 s).
    button =
      ~s|document.querySelector('section[data-panel="roadblock"] button[data-action="release"]')|

    :ok = Browser.wait(b, button, 90_000)

    img = ~s|document.querySelector('section[data-panel="roadblock"] img.panel-image')|
    :ok = Browser.wait(b, "#{img} && #{img}.complete && #{img}.naturalWidth > 0", 10_000)
    assert {:ok, w} = Browser.eval(b, "#{img}.naturalWidth")
    assert w >= 100

    assert {:ok, true} =
             Browser.eval(
               b,
               ~s|[...document.querySelectorAll('section[data-panel="roadblock"] td')].some(td => td.textContent === 'stopped')|
             )

    # The panel has a tab of its own.
    {:ok, true} =
      Browser.eval(
        b,
        ~s|document.querySelector('#tabs button[data-tab="panel:roadblock"]').click(); true|
      )

    {:ok, true} =
      Browser.eval(
        b,
        ~s|getComputedStyle(document.querySelector('section[data-panel="roadblock"]')).display !== 'none'|
      )

    File.mkdir_p!(Path.dirname(@screenshot))
    assert :ok = Browser.screenshot(b, @screenshot)

    {:ok, true} =
      Browser.eval(
        b,
        "document.getElementById('token').value = '#{@token}'; document.getElementById('token-set').click(); true"
      )

    {:ok, true} = Browser.eval(b, "#{button}.click(); true")

    assert {:ok, %{summary: s}} = TartarusRoadblock.await(120_000)
    assert s.rescued and s.chosen_robot == "claus" and s.santa_arrived
  end
end
