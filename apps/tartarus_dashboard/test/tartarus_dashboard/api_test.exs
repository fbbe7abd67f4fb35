defmodule TartarusDashboard.ApiTest do
  # The dashboard's JSON HTTP API over real HTTP (:httpc against the dashboard's server), on a
  # node with a few hosts of its own (no emulation): status codes, content types, what the
  # answers hold, bad input, the token, and the live stream.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport
  alias Tartarus.JSON

  doctest TartarusDashboard.Panel
  doctest TartarusDashboard.Term
  doctest TartarusDashboard.Processes

  @token "test-token-0123456789"

  defmodule CounterPanel do
    # A panel over an Elixir Agent holding a count: shows it, and "bump" adds params["by"].
    @behaviour TartarusDashboard.Panel
    def name(_), do: "counter"

    def render(agent) do
      %{
        title: "A counter",
        columns: ["name", "count"],
        rows: [["clicks", Agent.get(agent, & &1)]],
        actions: [%{action: "bump", label: "bump", params: %{by: 1}}]
      }
    end

    def act(agent, "bump", %{"by" => by}) when is_integer(by),
      do: {:ok, Agent.get_and_update(agent, &{&1 + by, &1 + by})}

    def act(_agent, action, _params), do: {:error, {:unknown_action, action}}
  end

  setup do
    n = System.unique_integer([:positive])
    a = :"dash_a_#{n}"
    b = :"dash_b_#{n}"
    {:ok, ha} = Tartarus.start_host(a, strict_links: true)
    {:ok, hb} = Tartarus.start_host(b, neighbours: [a])
    {:ok, id} = Tartarus.create_mobile_agent(a, Tartarus.Examples.Echo, nil)

    {:ok, dash} =
      TartarusDashboard.start_link(token: @token, max_body: 1_024, batch_ms: 50, max_batch: 50)

    on_exit(fn ->
      Tartarus.stop_host(a)
      Tartarus.stop_host(b)
    end)

    %{
      dash: dash,
      url: TartarusDashboard.url(dash),
      a: to_string(a),
      b: to_string(b),
      ha: ha,
      hb: hb,
      id: id
    }
  end

  defp get(url, path), do: request(:get, url <> String.trim_leading(path, "/"), nil, [])

  defp post(url, path, body, token \\ @token) do
    headers =
      if token, do: [{~c"authorization", String.to_charlist("Bearer " <> token)}], else: []

    request(:post, url <> String.trim_leading(path, "/"), body, headers)
  end

  defp request(method, url, body, headers) do
    req =
      if method == :post,
        do: {String.to_charlist(url), headers, ~c"application/json", body || ""},
        else: {String.to_charlist(url), headers}

    {:ok, {{_, status, _}, resp_headers, resp_body}} =
      :httpc.request(method, req, [timeout: 10_000], body_format: :binary)

    type = resp_headers |> List.keyfind(~c"content-type", 0) |> elem(1) |> to_string()
    decoded = if type =~ "json", do: JSON.decode!(resp_body), else: resp_body
    {status, type, decoded}
  end

  test "the page is HTML served by the node itself, with no script from elsewhere", %{url: url} do
    {200, type, html} = get(url, "/")
    assert type =~ "text/html"
    assert html =~ "<title>Tartarus dashboard</title>"
    assert html =~ "new EventSource(\"/api/stream\")"
    refute html =~ ~r/<script[^>]+src=/
    refute html =~ ~r/(src|href)=["']?(https?:)?\/\//
    refute html =~ ~r/(fetch|EventSource)\(["'`]https?:/
  end

  test "GET /api/hosts, /api/links, /api/agents, /api/summary describe the node", c do
    {200, "application/json", hosts} = get(c.url, "/api/hosts")
    ours = Map.new(for h <- hosts["hosts"], h["id"] in [c.a, c.b], do: {h["id"], h})
    assert ours[c.a]["residents"] == 1 and ours[c.b]["residents"] == 0
    assert ours[c.a]["node"] == to_string(node()) and ours[c.a]["up"] == true
    assert hosts["total"] >= 2

    {200, _, links} = get(c.url, "/api/links")

    assert %{"a" => _, "b" => _, "up" => true} =
             Enum.find(links["links"], &(Enum.sort([&1["a"], &1["b"]]) == Enum.sort([c.a, c.b])))

    {200, _, agents} = get(c.url, "/api/agents?host=#{c.a}")

    assert [%{"id" => id, "host" => host, "module" => "Tartarus.Examples.Echo"}] =
             agents["agents"]

    assert id == c.id and host == c.a

    {200, _, summary} = get(c.url, "/api/summary")
    assert summary["hosts"] >= 2 and is_list(summary["buckets"]) and is_list(summary["by_node"])

    {200, _, detail} = get(c.url, "/api/hosts/#{c.a}")
    assert [%{"id" => ^id}] = detail["agents"]

    {200, _, agent} = get(c.url, "/api/agents/#{c.id}")
    assert agent["id"] == c.id and agent["host"] == c.a

    {200, _, %{"catalog" => [%{"module" => "Tartarus.Examples.Echo"}]}} =
      get(c.url, "/api/catalog")
  end

  test "bad reads get clear 4xx JSON errors", c do
    assert {404, "application/json", %{"error" => "unknown_host", "message" => msg}} =
             get(c.url, "/api/hosts/no_such_host")

    assert msg =~ "no_such_host"
    assert {400, _, %{"error" => "bad_agent_id"}} = get(c.url, "/api/agents/not-an-id")
    assert {404, _, %{"error" => "unknown_agent"}} = get(c.url, "/api/agents/0123456789abcdef")

    assert {400, _, %{"error" => "bad_param", "message" => m}} =
             get(c.url, "/api/hosts?limit=lots")

    assert m =~ "limit must be an integer"
    assert {400, _, %{"error" => "bad_param"}} = get(c.url, "/api/hosts?sort=colour")
    assert {404, _, %{"error" => "unknown_host"}} = get(c.url, "/api/agents?host=nowhere")
    assert {404, _, %{"error" => "not_found"}} = get(c.url, "/api/nothing")
    assert {405, _, %{"error" => "method_not_allowed"}} = post(c.url, "/api/hosts", "{}")
    assert {405, _, %{"error" => "method_not_allowed"}} = get(c.url, "/api/links/break")
  end

  test "actions need the token: none is 401, a wrong one 403, and nothing happens", c do
    assert {401, "application/json", %{"error" => "token_required", "message" => m}} =
             post(c.url, "/api/agents/#{c.id}/kill", "", nil)

    assert m =~ "read-only"

    assert {403, _, %{"error" => "bad_token"}} =
             post(c.url, "/api/agents/#{c.id}/kill", "", "wrong-token-000")

    assert {403, _, _} = post(c.url, "/api/agents/#{c.id}/move", ~s({"to":"#{c.b}"}), "x")
    assert {:ok, host} = Tartarus.whereis({c.id, c.ha})
    assert host == c.ha
  end

  test "bad bodies and parameters get 4xx errors naming the problem", c do
    big = JSON.encode!(%{to: c.b, pad: String.duplicate("x", 2_000)})

    assert {413, _, %{"error" => "body_too_large", "message" => m}} =
             post(c.url, "/api/agents/#{c.id}/move", big)

    assert m =~ "at most 1024"
    assert {400, _, %{"error" => "bad_json"}} = post(c.url, "/api/agents/#{c.id}/move", "{to:")
    assert {400, _, %{"error" => "bad_json"}} = post(c.url, "/api/agents/#{c.id}/move", "[1]")
    assert {400, _, %{"error" => "missing_param"}} = post(c.url, "/api/agents/#{c.id}/move", "{}")

    assert {400, _, %{"error" => "bad_param"}} =
             post(c.url, "/api/agents/#{c.id}/move", ~s({"to":3}))

    assert {404, _, %{"error" => "unknown_host"}} =
             post(c.url, "/api/agents/#{c.id}/move", ~s({"to":"mars"}))

    assert {400, _, %{"error" => "bad_agent_id"}} = post(c.url, "/api/agents/xyz/kill", "")

    assert {404, _, %{"error" => "unknown_module", "message" => m}} =
             post(c.url, "/api/agents", ~s({"host":"#{c.a}","module":"Elixir.File"}))

    assert m =~ "catalog"

    assert {404, _, %{"error" => "not_emulated"}} =
             post(c.url, "/api/links/break", ~s({"a":"#{c.a}","b":"#{c.b}"}))

    assert {404, _, %{"error" => "not_found"}} = post(c.url, "/api/agents/#{c.id}/explode", "")
    assert {:ok, host} = Tartarus.whereis({c.id, c.ha})
    assert host == c.ha
  end

  test "actions go through the Tartarus API: create, move, post, clone, kill", c do
    {201, _, %{"id" => new, "host" => host}} =
      post(c.url, "/api/agents", ~s({"host":"#{c.a}","module":"Tartarus.Examples.Echo"}))

    assert host == c.a
    assert {:ok, _} = Tartarus.whereis({new, c.ha})

    assert {200, _, %{"ok" => true, "host" => b}} =
             post(c.url, "/api/agents/#{c.id}/move", ~s({"to":"#{c.b}"}))

    assert b == c.b
    assert {:ok, c.hb} == Tartarus.whereis({c.id, c.ha})

    assert {200, _, %{"ok" => true}} =
             post(c.url, "/api/agents/#{c.id}/post", ~s({"message":{"note":"hi"}}))

    assert {:ok, %{"note" => "hi"}} = Tartarus.request({c.id, c.hb}, :state)

    assert {200, _, %{"clone" => clone}} =
             post(c.url, "/api/agents/#{c.id}/clone", ~s({"to":"here"}))

    assert {:ok, c.hb} == Tartarus.whereis({clone, c.hb})

    assert {200, _, %{"ok" => true}} = post(c.url, "/api/agents/#{c.id}/kill", "")
    assert {:error, _} = Tartarus.whereis({c.id, c.hb})

    # A move the platform refuses is an error in plain words, not a crash.
    {201, _, %{"id" => lone}} =
      post(c.url, "/api/agents", ~s({"host":"#{c.a}","module":"Tartarus.Examples.Echo"}))

    {:ok, _} = Tartarus.start_host(:"#{c.a}_island")
    on_exit(fn -> Tartarus.stop_host(:"#{c.a}_island") end)
    # The dashboard reads the hosts again once its cached view is a second old.
    eventually(fn -> match?({200, _, _}, get(c.url, "/api/hosts/#{c.a}_island")) end)

    assert {422, _, %{"error" => "action_failed", "message" => m}} =
             post(c.url, "/api/agents/#{lone}/move", ~s({"to":"#{c.a}_island"}))

    assert m =~ "move failed"

    {200, _, events} = get(c.url, "/api/events?type=arrival&agent=#{c.id}")
    assert [%{"type" => "arrival", "host" => ^b, "from" => from}] = events["events"]
    assert from == c.a
  end

  test "an Elixir term is read as data, never run: a request's reply, a post between agents", c do
    assert {200, _, %{"reply" => "{:pong, 1}", "message" => "{:ping, 1}"}} =
             post(c.url, "/api/agents/#{c.id}/request", ~s({"term":"{:ping, 1}"}))

    # Text that is not a literal is refused with what it was; nothing runs.
    for {text, why} <- [
          {"System.halt()", "a call"},
          {"x", "a variable"},
          {~S|{:ok, File.rm!("/tmp/x")}|, "a call"},
          {~S|"a" <> "b"|, "a call"},
          {"~w(a b)", "a call"},
          {"@doc", "a module attribute"}
        ] do
      assert {400, _, %{"error" => "bad_term", "message" => m}} =
               post(c.url, "/api/agents/#{c.id}/request", JSON.encode!(%{term: text}))

      assert m =~ "not a literal term", text
      assert m =~ why, text
    end

    # No atom is made from the text.
    assert {400, _, %{"error" => "bad_term", "message" => m}} =
             post(c.url, "/api/agents/#{c.id}/post", ~s({"term":"{:no_such_atom_q7x2, 1}"}))

    assert m =~ "no atom no_such_atom_q7x2 exists on this node"

    assert_raise ArgumentError, fn -> String.to_existing_atom("no_such_atom_q7x2") end

    # An agent tells another: the message event names its sender (the first agent).
    {:ok, other} = Tartarus.create_mobile_agent(c.ha, Tartarus.Examples.Echo, nil, name: "o")
    term = ~s({:tell, "#{other}", {:ping, 2}})

    assert {200, _, %{"ok" => true}} =
             post(c.url, "/api/agents/#{c.id}/post", JSON.encode!(%{term: term}))

    eventually(fn ->
      {200, _, %{"events" => events}} = get(c.url, "/api/events?type=message&agent=#{other}")

      Enum.any?(
        events,
        &(&1["sender"] == c.id and &1["message"] == "{:ping, 2}" and &1["kind"] == "post")
      )
    end)

    # The sender's filter finds it too (an agent's sent messages are on its page).
    {200, _, %{"events" => sent}} = get(c.url, "/api/events?type=message&agent=#{c.id}")
    assert Enum.any?(sent, &(&1["sender"] == c.id and &1["agent"] == other))
    assert {:ok, {:ping, 2}} = Tartarus.request({other, c.ha}, :state)
  end

  test "the token is checked when entered: POST /api/token", c do
    assert {200, _, %{"ok" => true}} = post(c.url, "/api/token", "")
    assert {403, _, %{"error" => "bad_token"}} = post(c.url, "/api/token", "", "wrong-token")
    assert {401, _, %{"error" => "token_required"}} = post(c.url, "/api/token", "", nil)
  end

  test "GET /api/processes: this node's top processes, its agents named", c do
    {200, _, r} = get(c.url, "/api/processes?sort=memory&limit=5")
    assert r["node"] == to_string(node()) and r["sort"] == "memory"
    assert length(r["processes"]) == 5
    mem = Enum.map(r["processes"], & &1["memory"])
    assert mem == Enum.sort(mem, :desc)

    # An agent with a long mailbox heads the list by mailbox, named by its id and module.
    {:ok, pid, _} = Tartarus.AgentTable.lookup(c.id)
    :erlang.suspend_process(pid)
    for i <- 1..500, do: send(pid, {:junk, i})
    {200, _, r} = get(c.url, "/api/processes?sort=mailbox&limit=3")
    :erlang.resume_process(pid)
    assert [%{"kind" => "agent", "name" => name, "mailbox" => n} | _] = r["processes"]
    assert name =~ c.id and name =~ "Tartarus.Examples.Echo" and n >= 500

    assert {400, _, %{"error" => "bad_param"}} = get(c.url, "/api/processes?sort=age")
    assert {404, _, %{"error" => "unknown_node"}} = get(c.url, "/api/processes?node=nope@nowhere")
  end

  test "the live stream sends batches of events as server-sent events", c do
    {:ok, sock} =
      :gen_tcp.connect(~c"127.0.0.1", TartarusDashboard.port(c.dash), [:binary, active: false])

    :ok = :gen_tcp.send(sock, "GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    {:ok, head} = :gen_tcp.recv(sock, 0, 5_000)
    assert head =~ "200 OK"
    assert head =~ "Content-Type: text/event-stream"

    :ok = Tartarus.move({c.id, c.ha}, c.hb)
    text = read_until(sock, head, ~s("type":"arrival"), 5_000)
    :gen_tcp.close(sock)

    [data] =
      Regex.run(~r/event: batch\ndata: (.*)\n/, text, capture: :all_but_first) |> then(&[hd(&1)])

    batch = JSON.decode!(data)

    assert Enum.any?(
             batch["events"],
             &(&1["type"] == "arrival" and &1["agent"] == c.id and &1["host"] == c.b)
           )
  end

  test "a batch holds at most max_batch events; the rest are counted as dropped" do
    {:ok, dash} = TartarusDashboard.start_link(max_batch: 3, batch_ms: 200)

    {:ok, sock} =
      :gen_tcp.connect(~c"127.0.0.1", TartarusDashboard.port(dash), [:binary, active: false])

    :ok = :gen_tcp.send(sock, "GET /api/stream HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
    {:ok, _} = :gen_tcp.recv(sock, 0, 5_000)
    # The stream is joined once the head is out; now make 12 events.
    h = :"dash_burst_#{System.unique_integer([:positive])}"
    {:ok, _} = Tartarus.start_host(h)
    on_exit(fn -> Tartarus.stop_host(h) end)
    for _ <- 1..12, do: {:ok, _} = Tartarus.create_mobile_agent(h, Tartarus.Examples.Echo, nil)

    batches = read_batches(sock, "", 0, 12)
    :gen_tcp.close(sock)
    assert Enum.all?(batches, &(length(&1["events"]) <= 3))

    created =
      for b <- batches, e <- b["events"], e["type"] == "created", e["host"] == to_string(h), do: e

    assert length(created) + Enum.sum(Enum.map(batches, & &1["dropped"])) >= 12
    assert Enum.sum(Enum.map(batches, & &1["dropped"])) > 0
  end

  defmodule PicturePanel do
    @moduledoc false
    # A panel with a picture (and one with a type the page does not show).
    @behaviour TartarusDashboard.Panel
    def name(type), do: "pic-" <> String.replace(type, ~r/[^a-z]/, "")

    def render(type),
      do: %{
        title: "A picture",
        columns: [],
        rows: [],
        image: %{type: type, data: <<137, 80, 78, 71>>, alt: "four bytes"}
      }

    def act(_, action, _), do: {:error, {:unknown_action, action}}
  end

  test "a panel's picture is served inline as a data URL; a type the page does not show is dropped" do
    {:ok, dash} =
      TartarusDashboard.start_link(
        token: @token,
        panels: [{PicturePanel, "image/png"}, {PicturePanel, "text/html"}]
      )

    {200, _, %{"panels" => [png, html]}} = get(TartarusDashboard.url(dash), "/api/panels")
    assert png["image"] == "data:image/png;base64," <> Base.encode64(<<137, 80, 78, 71>>)
    assert png["image_alt"] == "four bytes"
    assert html["image"] == nil
  end

  test "an application's panel is shown and acts, with the token" do
    {:ok, counter} = Agent.start_link(fn -> 0 end)
    {:ok, dash} = TartarusDashboard.start_link(token: @token, panels: [{CounterPanel, counter}])
    url = TartarusDashboard.url(dash)

    {200, _, %{"panels" => [panel]}} = get(url, "/api/panels")
    assert %{"name" => "counter", "title" => "A counter", "rows" => [["clicks", 0]]} = panel
    assert [%{"action" => "bump", "params" => %{"by" => 1}}] = panel["actions"]

    assert {401, _, _} = post(url, "/api/panels/counter/bump", ~s({"by":2}), nil)

    assert {200, _, %{"ok" => true, "result" => 2}} =
             post(url, "/api/panels/counter/bump", ~s({"by":2}))

    assert Agent.get(counter, & &1) == 2
    assert {422, _, %{"message" => m}} = post(url, "/api/panels/counter/explode", "{}")
    assert m =~ "explode failed"
    assert {404, _, %{"error" => "unknown_panel"}} = post(url, "/api/panels/nope/bump", "{}")
  end

  test "the token can come from a file; a bad token option is refused" do
    path = Path.join(System.tmp_dir!(), "dash_token_#{System.unique_integer([:positive])}")
    File.write!(path, "from-a-file-123\nignored\n")
    on_exit(fn -> File.rm(path) end)
    {:ok, dash} = TartarusDashboard.start_link(token_file: path)
    assert TartarusDashboard.token(dash) == "from-a-file-123"
    assert {:error, msg} = TartarusDashboard.start_link(token: "short")
    assert msg =~ "[:token]"
    assert {:error, msg} = TartarusDashboard.start_link(token_file: path <> ".missing")
    assert msg =~ "token file"
  end

  defp read_until(sock, acc, needle, timeout) do
    if acc =~ needle do
      acc
    else
      {:ok, more} = :gen_tcp.recv(sock, 0, timeout)
      read_until(sock, acc <> more, needle, timeout)
    end
  end

  # Reads batches until `want` created events and drops are accounted for (or 5 s).
  defp read_batches(sock, buf, seen, want) do
    case :gen_tcp.recv(sock, 0, 5_000) do
      {:ok, more} ->
        buf = buf <> more

        batches =
          for [d] <- Regex.scan(~r/data: (\{.*\})\n/, buf, capture: :all_but_first),
              do: JSON.decode!(d)

        total = Enum.sum(for b <- batches, do: length(b["events"]) + b["dropped"])

        if total >= want or seen > 50, do: batches, else: read_batches(sock, buf, seen + 1, want)

      {:error, _} ->
        for [d] <- Regex.scan(~r/data: (\{.*\})\n/, buf, capture: :all_but_first),
            do: JSON.decode!(d)
    end
  end
end
