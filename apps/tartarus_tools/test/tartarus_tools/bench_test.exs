defmodule TartarusTools.BenchTest do
  # The benchmarks' code paths at tiny sizes: keys and invariants, never timings.
  use ExUnit.Case, async: false

  alias TartarusTools.Bench

  test "the floor moves every agent through all its hops" do
    state = %{left: 0, b: nil, blob: :crypto.strong_rand_bytes(16)}
    assert is_integer(Bench.Floor.run(node(), 3, 5, state))
    assert is_integer(Bench.Floor.run(node(), 1, 1, state))
  end

  test "migration (virtual) reports the platform, the floor and their ratios" do
    r = Bench.migration(mode: :virtual, latency_hops: 10, agents: 4, hops: 5, state_bytes: 64)

    for key <- [
          :us_per_hop,
          :floor_us_per_hop,
          :ratio_latency,
          :hops_per_s,
          :floor_hops_per_s,
          :ratio_throughput,
          :median_us,
          :p99_us
        ] do
      assert is_number(r[key]) and r[key] > 0, "#{key}: #{inspect(r[key])}"
    end

    assert %{total_hops: 20, agents: 4, hops: 5, latency_hops: 10, mode: :virtual} = r
    assert r.samples == 10
    assert_in_delta r.ratio_latency, r.us_per_hop / r.floor_us_per_hop, 0.01
    json = Tartarus.JSON.encode!(r)
    assert json =~ ~s("floor_us_per_hop":)
    assert json =~ ~s("ratio_throughput":)
  end

  test "churn reports the memory at each checkpoint, with and without a journal" do
    r = Bench.Churn.run(migrations: 300, agents: 10, hops: 5, persist: true)
    assert r.checkpoints == [300]
    assert %{"300" => bytes} = r.memory_bytes_at
    assert bytes > 0
    assert %{"300" => %{host_tables: t, agent_table: _, journal: 0, entries: e}} = r.tables_at
    assert t > 0 and is_map(e)
    assert %{"300" => j} = r.persist.journal_bytes_at
    assert j > 0
    assert r.persist.memory_bytes_at["300"] >= j
    # Measured once the agents' ends were handled: no agent process left on either host.
    assert %{"300" => settle} = r.settle_ms_at
    assert is_integer(settle) and is_integer(r.persist.settle_ms_at["300"])
    refute Map.has_key?(r.tables_at["300"].entries, ":proc")
    refute Map.has_key?(r.persist.tables_at["300"].entries, ":proc")
    # Every agent ended: none is resident any more.
    assert Tartarus.hosts() == []
  end

  test "busy (two hosts in one VM): every acknowledged message is in the agent's state" do
    tag = System.unique_integer([:positive])
    {:ok, h2} = Tartarus.start_host(:"busy_test_#{tag}")

    try do
      r = Bench.Busy.drive(h2, messages: 60, senders: 3, dwell_ms: 2, timeout: 2_000)
      assert r.messages == 60 and r.senders == 3 and r.sent == 60
      assert r.acknowledged + r.failed == r.sent
      assert r.acknowledged_missing == 0
      assert r.duplicates == 0
      assert r.order_kept
      assert r.delivered_exactly_once <= r.delivered
      assert r.delivered >= r.acknowledged
      assert is_map(r.failures)
    after
      Tartarus.stop_host(h2)
    end
  end

  test "the hopper's bitmap records each message once" do
    assert TartarusTools.Bench.Busy.Hopper.bit(<<0b0100_0000>>, 1)
    refute TartarusTools.Bench.Busy.Hopper.bit(<<0b0100_0000>>, 0)
    refute TartarusTools.Bench.Busy.Hopper.bit(<<0::4>>, 9)
  end

  test "durability reports hops and posts per second for memory, journal and durable" do
    r = Bench.Durability.run(agents: 3, hops: 4, messages: 40, senders: 2)
    assert %{agents: 3, hops: 4, messages: 40, senders: 2} = r

    for c <- [:memory, :journal, :durable], key <- [:hops_per_s, :posts_per_s, :us_per_post] do
      assert r.configs[c][key] > 0, "#{c} #{key}"
    end

    assert r.configs.memory.journal_bytes == 0
    assert r.configs.durable.journal_bytes > 0
    assert r.durable_posts_ratio > 0 and r.durable_hops_ratio > 0
  end
end
