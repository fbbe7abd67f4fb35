defmodule TartarusDashboard.HealthTest do
  # The health sampler (a bounded ring of samples, each bounded in what it reads), the
  # per-second event counts and the fleet, health and rates endpoints on a node of its own.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport
  alias TartarusDashboard.{Feed, Health}
  alias Tartarus.JSON

  defp get(url, path) do
    {:ok, status, body} = TartarusDashboard.http_get(url <> path)
    {status, JSON.decode!(body)}
  end

  test "utilisation from two scheduler readings; the longest mailboxes first" do
    assert Health.utilisation([{1, 0, 0}, {2, 0, 0}], [{1, 50, 100}, {2, 0, 100}]) == 0.25
    assert Health.utilisation(nil, [{1, 5, 10}]) == nil
    assert Health.utilisation([{1, 5, 10}], [{1, 5, 10}]) == nil

    assert Health.longest([%{len: 1}, %{len: 7}, %{len: 3}], 2) == [%{len: 7}, %{len: 3}]
  end

  test "the ring keeps the last :keep samples; agents' mailboxes are read, named" do
    Health.stop()
    on_exit(&Health.stop/0)
    n = System.unique_integer([:positive])
    {:ok, h} = Tartarus.start_host(:"health_#{n}")
    on_exit(fn -> Tartarus.stop_host(h) end)
    {:ok, id} = Tartarus.create_mobile_agent(h, Tartarus.Examples.Echo, nil, name: "loaded")
    {:ok, pid, _} = Tartarus.AgentTable.lookup(id)
    # A mailbox that fills up: the agent is suspended, its messages wait.
    :erlang.suspend_process(pid)
    for i <- 1..50, do: send(pid, {:junk, i})

    Health.ensure_started(every_ms: 20, keep: 5, max_agents: 10)

    full = fn ->
      s = Health.series(100)
      length(s) == 5 and Enum.any?(s, &(&1.mailbox_max >= 50)) and s
    end

    samples = eventually(full, 30_000)
    :erlang.resume_process(pid)
    last = Enum.find(Enum.reverse(samples), &(&1.mailbox_max >= 50))
    assert [%{id: ^id, name: "loaded", len: len} | _] = last.mailboxes
    assert len >= 50
    assert %{total: t, processes: _, ets: _, binary: _} = last.memory
    assert t > 0 and last.processes > 0 and is_list(last.run_queues)
    assert Map.has_key?(last.hosts, "health_#{n}")
    assert last.cost_us >= 0 and last.cost_reductions > 0
  end

  test "events are counted per type per second, exactly, though the feed receives few" do
    n = System.unique_integer([:positive])
    {:ok, a} = Tartarus.start_host(:"rate_a_#{n}")
    {:ok, b} = Tartarus.start_host(:"rate_b_#{n}")
    on_exit(fn -> Enum.each([a, b], &Tartarus.stop_host/1) end)
    :ok = Tartarus.connect(a, b)
    {:ok, id} = Tartarus.create_mobile_agent(a, Tartarus.Examples.Echo, nil)

    # A budget of one event per second: the platform sends the feed almost none of them.
    {:ok, feed} = Feed.start_link(batch_ms: 1_000, max_batch: 1, recent: 100)
    on_exit(fn -> Feed.stop(feed) end)
    # A call: the feed has read its starting counts before the moves.
    _ = Feed.stats(feed)

    Enum.reduce(1..6, a, fn _, at ->
      to = if at == a, do: b, else: a
      :ok = Tartarus.move({id, at}, to)
      to
    end)

    rates =
      eventually(fn ->
        r = Feed.rates(feed, 10)
        Enum.sum(r.counts[:arrival] || [0]) == 6 && r
      end)

    assert Enum.sum(rates.counts[:departure]) == 6
    assert length(rates.t) == length(rates.counts[:arrival])
    stats = Feed.stats(feed)
    assert stats.counts[:arrival] == 6
    # Received: at most a couple (one per one-second window); the rest were skipped, counted.
    assert stats.seq <= 4 and stats.dropped >= 8
  end

  test "/api/fleet, /api/health and /api/rates on a node of its own" do
    n = System.unique_integer([:positive])
    {:ok, h} = Tartarus.start_host(:"hf_#{n}")
    on_exit(fn -> Tartarus.stop_host(h) end)
    # A sampler started now: its first sample (taken at once) has the new host.
    Health.stop()
    on_exit(&Health.stop/0)
    {:ok, dash} = TartarusDashboard.start_link(token: "health-test-token")
    url = TartarusDashboard.url(dash)

    {200, fleet} = get(url, "api/fleet")
    me = Enum.find(fleet["nodes"], &(&1["node"] == to_string(node())))
    assert me["reachable"] and "hf_#{n}" in me["hosts"]
    assert %{"memory" => %{"total" => _}, "processes" => _} = me["health"]
    assert fleet["kept"] == false

    {200, health} = get(url, "api/health?points=5")
    assert health["node"] == to_string(node())
    assert length(health["points"]) in 1..5
    assert "hf_#{n}" in health["hosts"]

    {200, per_host} = get(url, "api/health?host=hf_#{n}")
    assert [%{"residents" => 0, "t" => _} | _] = per_host["points"]

    {200, %{"t" => [_ | _], "counts" => %{}}} = get(url, "api/rates?seconds=5")
    assert {404, %{"error" => "unknown_node"}} = get(url, "api/health?node=nowhere@nohost")
    assert {400, %{"error" => "bad_param"}} = get(url, "api/rates?seconds=0")
    TartarusDashboard.stop(dash)
  end
end
