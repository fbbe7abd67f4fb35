defmodule TartarusEmu.DashboardTest do
  # The dashboard over an emulated network, through its JSON HTTP API: the emulation's
  # hosts and links, the link actions (break, heal, isolate, rejoin) carried out by
  # TartarusEmu.Network, and a scenario run with `dashboard:`.
  use ExUnit.Case, async: false

  import TartarusEmu.EmuCase
  import Tartarus.TestSupport
  alias TartarusEmu.{Network, Topology}
  alias Tartarus.JSON

  @token "emu-test-token"

  setup do
    net = start_network!(Topology.grid(2, 3))
    {:ok, dash} = TartarusEmu.Dashboard.start_link(net, token: @token)
    %{net: net, url: TartarusDashboard.url(dash)}
  end

  defp get(url, path) do
    {:ok, status, body} = TartarusDashboard.http_get(url <> String.trim_leading(path, "/"))
    {status, JSON.decode!(body)}
  end

  defp post(url, path, body) do
    headers = [{~c"authorization", String.to_charlist("Bearer " <> @token)}]

    req =
      {String.to_charlist(url <> String.trim_leading(path, "/")), headers, ~c"application/json",
       body}

    {:ok, {{_, status, _}, _, resp}} = :httpc.request(:post, req, [], body_format: :binary)
    {status, JSON.decode!(resp)}
  end

  test "hosts are the topology's nodes, with their BEAM node and positions", %{url: url, net: net} do
    {200, %{"hosts" => hosts, "total" => 6}} = get(url, "/api/hosts")
    assert Enum.map(hosts, & &1["id"]) == ~w(h1 h2 h3 h4 h5 h6)

    assert Enum.all?(
             hosts,
             &(&1["up"] and &1["node"] == to_string(node()) and is_list(&1["pos"]))
           )

    {200, %{"links" => links}} = get(url, "/api/links")
    assert length(links) == Topology.edge_count(net.topology)
    assert Enum.all?(links, & &1["up"])
  end

  test "break and heal a link, isolate a host and let it rejoin", %{url: url, net: net} do
    assert {200, %{"ok" => true}} = post(url, "/api/links/break", ~s({"a":"h1","b":"h2"}))
    refute Network.live?(net, :h1, :h2)

    eventually(fn ->
      {200, %{"links" => links}} = get(url, "/api/links")
      match?(%{"up" => false}, Enum.find(links, &(&1["a"] == "h1" and &1["b"] == "h2")))
    end)

    assert {200, _} = post(url, "/api/links/heal", ~s({"a":"h1","b":"h2"}))
    assert Network.live?(net, :h1, :h2)

    assert {200, %{"host" => "h5"}} = post(url, "/api/hosts/h5/isolate", "")
    refute Network.up?(net, :h5)
    {200, %{"up" => false}} = get(url, "/api/hosts/h5")
    assert {200, _} = post(url, "/api/hosts/h5/rejoin", "")
    assert Network.up?(net, :h5)

    # Not an edge of the topology: the emulator's refusal, in words.
    assert {422, %{"error" => "action_failed", "message" => m}} =
             post(url, "/api/links/break", ~s({"a":"h1","b":"h6"}))

    assert m =~ "no link between h1 and h6"
    assert {404, %{"error" => "unknown_host"}} = post(url, "/api/hosts/h99/isolate", "")
  end

  test "a function as the network: the page shows whichever network it returns now", %{net: net} do
    slot = :ets.new(:dash_slot, [:public])
    current = fn -> with [{:net, n}] <- :ets.lookup(slot, :net), do: n, else: (_ -> nil) end
    {:ok, dash} = TartarusEmu.Dashboard.start_link(current, token: @token)
    url = TartarusDashboard.url(dash)

    # None yet: no hosts, no links, and link actions refused.
    assert {200, %{"hosts" => [], "total" => 0}} = get(url, "/api/hosts")
    assert {200, %{"links" => []}} = get(url, "/api/links")
    assert TartarusEmu.Dashboard.act(current, :isolate, %{host: "h1"}) == {:error, :no_network}

    :ets.insert(slot, {:net, net})

    eventually(fn -> match?({200, %{"total" => 6}}, get(url, "/api/hosts")) end)
    assert {200, %{"ok" => true}} = post(url, "/api/links/break", ~s({"a":"h1","b":"h2"}))
    refute Network.live?(net, :h1, :h2)
    TartarusDashboard.stop(dash)
  end

  test "events name hosts by their topology names", %{url: url, net: net} do
    {:ok, id} = Tartarus.create_mobile_agent(Network.host(net, :h1), Tartarus.Examples.Echo, nil)
    :ok = Tartarus.move({id, Network.host(net, :h1)}, Network.host(net, :h2))

    eventually(fn ->
      match?({200, %{"events" => [_]}}, get(url, "/api/events?type=arrival&agent=#{id}"))
    end)

    {200, %{"events" => [e]}} = get(url, "/api/events?type=arrival&agent=#{id}")
    assert %{"host" => "h2", "from" => "h1", "agent" => ^id} = e
    {200, %{"agents" => [%{"id" => ^id, "host" => "h2"}]}} = get(url, "/api/agents?host=h2")
  end

  test "a scenario run serves the dashboard while it runs (runner option dashboard:)" do
    {:ok, dev} = StringIO.open("")

    {:ok, %{summary: summary}} =
      TartarusEmu.Scenario.run(TartarusEmu.Walk,
        hosts: 4,
        topology: "ring",
        agents: 2,
        steps: 3,
        seed: 1,
        out: false,
        progress_device: dev,
        quiet: true,
        dashboard: 0
      )

    assert summary.steps == 3
    {_, printed} = StringIO.contents(dev)
    assert [_, url] = Regex.run(~r{dashboard: (http://127\.0\.0\.1:\d+/)}, printed)
    # Stopped with the run.
    assert {:error, _} = TartarusDashboard.http_get(url <> "api/info", 2_000)
  end

  defmodule Tiny do
    # A scenario that tells the test when it is torn down.
    @behaviour TartarusEmu.Scenario
    def name, do: "tiny"

    def setup(opts) do
      {:ok, net} = TartarusEmu.Network.start(TartarusEmu.Topology.line(2))
      {:ok, %{net: net, test: opts.test}}
    end

    def step(s, _), do: s
    def series(_), do: TartarusTools.Series.new()
    def summary(_), do: %{}

    def teardown(s) do
      TartarusEmu.Network.stop(s.net)
      send(s.test, {:torn_down, s.net})
    end
  end

  test "a scenario whose dashboard cannot start (a bad token, a port in use) ends with the reason, torn down" do
    run = fn dashboard ->
      TartarusEmu.Scenario.run(Tiny,
        test: self(),
        steps: 1,
        seed: 1,
        out: false,
        quiet: true,
        dashboard: dashboard
      )
    end

    assert {:error, message} = run.(port: 0, token: "short")
    assert message =~ "token"
    assert_received {:torn_down, net}

    eventually(fn ->
      Enum.all?(net.topology.nodes, fn n ->
        match?({:error, _}, Tartarus.Host.whereis(TartarusEmu.Network.host(net, n)))
      end)
    end)

    # A port in use: the same, and the caller is not taken down with the web server.
    {:ok, l} = :gen_tcp.listen(0, ip: {127, 0, 0, 1})
    {:ok, port} = :inet.port(l)
    assert run.(port) == {:error, "dashboard: port #{port} is in use"}
    assert_received {:torn_down, _}
    :gen_tcp.close(l)
  end

  test "a kept page outlives its network: the last hosts, agents and health stay readable" do
    {:ok, net} = Network.start(Topology.grid(2, 2))
    {:ok, id} = Tartarus.create_mobile_agent(Network.host(net, :h1), Tartarus.Examples.Echo, nil)
    {:ok, dash} = TartarusEmu.Dashboard.start_link(net, token: @token)
    url = TartarusDashboard.url(dash)
    eventually(fn -> match?({200, %{"points" => [_ | _]}}, get(url, "/api/health")) end)

    :ok = TartarusDashboard.keep(dash)
    Network.stop(net)

    {200, %{"hosts" => hosts}} = get(url, "/api/hosts")
    assert Enum.map(hosts, & &1["id"]) == ~w(h1 h2 h3 h4)
    assert {200, %{"agents" => [%{"id" => ^id, "host" => "h1"}]}} = get(url, "/api/agents")
    assert {200, %{"links" => [_, _, _, _]}} = get(url, "/api/links")
    assert {200, %{"kept" => true}} = get(url, "/api/fleet")
    {200, %{"points" => kept}} = get(url, "/api/health")
    assert kept != []
    # The charts are the run's: they do not move on after it.
    Process.sleep(1_500)
    assert {200, %{"points" => ^kept}} = get(url, "/api/health")
    TartarusDashboard.stop(dash)
  end
end
