defmodule TartarusEmu.LogTest do
  use ExUnit.Case, async: true

  import TartarusEmu.EmuCase
  import Tartarus.TestSupport
  alias TartarusEmu.{Log, Network, Topology}

  doctest TartarusEmu.Log.Counts

  defmodule Hopper do
    use Tartarus.Agent
    def init(n), do: {:stay, n}
    def handle_message(:go, _from, n), do: {:move, :random, n}
    def handle_arrival(_ctx, 0), do: {:stay, 0}
    def handle_arrival(_ctx, n), do: {:move, :random, n - 1}
  end

  setup do
    net = start_network!(Topology.grid(2, 3))
    {:ok, log} = Log.start(net, keep_events: true, max_events: 50)
    on_exit(fn -> if Process.alive?(log), do: Log.stop(log) end)
    %{net: net, log: log}
  end

  defp run_hoppers(net, hops) do
    ids =
      for n <- [:h1, :h4, :h6] do
        {:ok, id} = Tartarus.create_mobile_agent(Network.host(net, n), Hopper, hops, seed: n)
        :ok = Tartarus.post({id, Network.host(net, n)}, :go)
        {id, Network.host(net, n)}
      end

    eventually(fn ->
      total =
        net |> Network.host_list() |> Enum.map(&Tartarus.status(&1).counts.arrivals) |> Enum.sum()

      total == 3 * (hops + 1)
    end)

    ids
  end

  test "per-host and per-link counts equal the platform's own counters", %{net: net, log: log} do
    run_hoppers(net, 20)
    :ok = Log.sync(log)
    counts = Log.counts(log)

    for host <- Network.host_list(net) do
      platform = Tartarus.status(host).counts
      ours = Map.get(counts.hosts, host, %{})

      for k <- [:created, :arrivals, :departures, :bytes, :code_bytes, :messages, :message_bytes] do
        assert Map.get(ours, k, 0) == platform[k], "#{inspect(host)} #{k}"
      end

      # Every departure from a host is counted on one of its links.
      out = for {{^host, _}, m} <- counts.links, reduce: 0, do: (acc -> acc + m.messages)
      assert out == platform.departures
    end

    assert counts.totals.arrivals == 63
    assert counts.totals.departures == 63
    # Links used are topology edges only (strict links).
    for {{from, to}, _} <- counts.links do
      assert Network.live?(net, Network.topo_node(net, from), Network.topo_node(net, to))
    end
  end

  test "broadcasts are counted as the platform counts them; settled totals wait for their reception",
       %{net: net, log: log} do
    sent =
      for n <- [:h1, :h2, :h3, :h4, :h5, :h6], reduce: 0 do
        acc ->
          {:ok, k} = Tartarus.broadcast(Network.host(net, n), {:hello, n})
          acc + k
      end

    t = Log.settled_totals(log)
    assert t.broadcasts == 6
    assert t.broadcast_messages == sent and t.broadcasts_received == sent

    platform =
      net
      |> Network.host_list()
      |> Enum.map(&Tartarus.status(&1).counts.broadcast_messages)
      |> Enum.sum()

    assert platform == sent
  end

  test "the step clock stamps events with the step they happened in", %{net: net, log: log} do
    assert Log.step(log) == 0
    {:ok, _} = Tartarus.create_mobile_agent(Network.host(net, :h1), Hopper, 0)
    assert Log.tick(log) == 1
    run_hoppers(net, 2)
    assert Log.tick(log) == 2

    assert Log.totals(log, 0).created == 1
    assert Log.totals(log, 1).created == 3
    assert Log.totals(log, 1).arrivals == 9
    assert Log.totals(log, 2).arrivals == 0
    assert Log.totals(log).arrivals == 9
  end

  test "raw events are bounded and exported as CSV", %{net: net, log: log} do
    run_hoppers(net, 20)
    :ok = Log.sync(log)
    {events, dropped} = Log.events(log)
    assert length(events) == 50
    assert length(events) + dropped == 3 + 63 * 2 + 3
    assert Enum.all?(events, &(&1.step == 0))
    assert hd(events).type == :created

    dir = Path.join(System.tmp_dir!(), "emu_log_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    paths = Log.write_csv!(log, dir)

    assert Enum.map(paths, &Path.basename/1) ==
             ~w(log_steps.csv log_hosts.csv log_links.csv log_events.csv)

    [header | rows] =
      dir |> Path.join("log_links.csv") |> File.read!() |> String.split("\n", trim: true)

    assert header == "from,to,messages,bytes"

    assert rows
           |> Enum.map(&(&1 |> String.split(",") |> Enum.at(2) |> String.to_integer()))
           |> Enum.sum() == 63
  end

  test "events of hosts outside the network are not counted", %{log: log} do
    {:ok, other} = Tartarus.start_host("outsider_#{System.unique_integer([:positive])}")
    on_exit(fn -> Tartarus.stop_host(other) end)
    {:ok, _} = Tartarus.create_mobile_agent(other, Hopper, 0)
    :ok = Log.sync(log)
    assert Log.totals(log).created == 0
  end
end
