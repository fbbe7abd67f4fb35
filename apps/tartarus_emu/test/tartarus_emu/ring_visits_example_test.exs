defmodule TartarusEmu.RingVisitsExample do
  @moduledoc false
  # The worked example of docs/emulator.md ("How an application plugs in"): a tiny
  # application (agents wandering a ring, a counter on every node) as a Scenario.
  @behaviour TartarusEmu.Scenario
  alias TartarusEmu.{Network, Topology}

  defmodule Counter do
    @moduledoc false
    use Tartarus.Agent
    def init(node), do: {:stay, %{node: node, visits: 0}}
    def handle_message(:visit, _from, s), do: {:stay, %{s | visits: s.visits + 1}}

    def handle_message(:count, from, s) do
      Tartarus.Agent.reply(from, s.visits)
      {:stay, s}
    end
  end

  defmodule Wanderer do
    @moduledoc false
    use Tartarus.Agent
    def init(driver), do: {:stay, driver}
    def handle_info(:go, driver), do: {:move, :random, driver}

    def handle_arrival(_ctx, driver) do
      :ok = Tartarus.post({"counter", Tartarus.Agent.host()}, :visit)
      send(driver, {:arrived, Tartarus.Agent.id()})
      {:stay, driver}
    end
  end

  def name, do: "ring_visits"

  def setup(opts) do
    # The per-node setup hook: the same in virtual and in peer mode.
    hook = fn node, host -> Tartarus.create_static_agent(host, Counter, node, name: "counter") end
    {:ok, net} = Network.start(Topology.ring(opts.nodes), mode: opts.mode, setup: hook)

    for i <- 1..opts.wanderers do
      {:ok, _} =
        Tartarus.create_mobile_agent(Network.host(net, :h1), Wanderer, self(),
          seed: {opts.seed, i}
        )
    end

    {:ok, %{net: net, wanderers: opts.wanderers, series: TartarusTools.Series.new()}}
  end

  # One step: every wanderer moves once (counters ignore :go); it ends when all have arrived.
  def step(state, k) do
    Network.broadcast(state.net, :go)
    for _ <- 1..state.wanderers, do: receive(do: ({:arrived, _} -> :ok))
    %{state | series: TartarusTools.Series.record(state.series, :busiest, k, busiest(state))}
  end

  def series(state), do: state.series
  def summary(state), do: %{visits: visits(state), busiest: busiest(state)}
  def teardown(state), do: Network.stop(state.net)

  defp busiest(state), do: state |> visits() |> Map.values() |> Enum.max()

  defp visits(state) do
    Map.new(state.net.hosts, fn {node, host} ->
      {:ok, n} = Tartarus.request({"counter", host}, :count)
      {node, n}
    end)
  end
end

defmodule TartarusEmu.RingVisitsExampleTest do
  use ExUnit.Case, async: false
  alias TartarusEmu.{RingVisitsExample, Scenario}

  @tag :tmp_dir
  test "the worked example runs as a Scenario: counts add up, same seed same counts", %{
    tmp_dir: dir
  } do
    opts = [nodes: 8, wanderers: 4, mode: :virtual, steps: 25, quiet: true]
    {:ok, a} = Scenario.run(RingVisitsExample, [seed: 5, out: dir] ++ opts)
    {:ok, b} = Scenario.run(RingVisitsExample, [seed: 5, out: false] ++ opts)
    {:ok, c} = Scenario.run(RingVisitsExample, [seed: 6, out: false] ++ opts)

    # Every move of every wanderer was counted once, on the node it arrived at.
    assert a.summary.visits |> Map.values() |> Enum.sum() == 25 * 4
    assert map_size(a.summary.visits) == 8
    assert a.summary.visits == b.summary.visits
    refute a.summary.visits == c.summary.visits
    assert a.summary.seed == 5 and a.summary.steps == 25

    for f <- ~w(series.csv busiest.csv busiest.svg summary.json summary.md),
        do: assert(File.exists?(Path.join(dir, f)), f)
  end
end
