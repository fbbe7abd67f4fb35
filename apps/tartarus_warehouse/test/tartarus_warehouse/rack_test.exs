defmodule TartarusWarehouse.RackTest do
  # The racks of §4.7.1 (Φ nodes' static agents) on a floor in virtual time, so the
  # round trips to them are the links' latencies, not the machine's.
  use ExUnit.Case, async: false
  doctest TartarusWarehouse.Rack

  alias Tartarus.Clock
  alias TartarusWarehouse.{Checker, Floor}
  alias TartarusWarehouse.Experiment.Jobs

  # 2 jobs of 3 soft tasks (task i needs ψi) on 4 robots with 2 Φ nodes, 10 ms a link.
  defp run_floor(extra) do
    jobs = Jobs.soft_jobs(2, 3, 2000)

    {:ok, r} =
      Clock.Virtual.run([seed: 5], fn ->
        Floor.run([robots: 4, phi: 2, jobs: jobs, scale: 0.01, latency_ms: 10, seed: 5] ++ extra)
      end)

    {jobs, r}
  end

  test "with racks, each task's code reaches its resource's rack before its robot runs it" do
    {jobs, r} = run_floor(phi_agents: true)

    assert Checker.violations(r.history) == []
    assert length(Checker.completion(r.history, jobs).completed) == 2

    # ψ1 and ψ3 are on f1, ψ2 on f2; each job's task brought its code once.
    by_rack =
      Map.new(r.rack_codes, fn {rack, codes} ->
        {rack, codes |> Enum.map(fn {_agent, task, _program} -> task end) |> Enum.sort()}
      end)

    assert by_rack == %{"f1" => ["T1", "T1", "T3", "T3"], "f2" => ["T2", "T2"]}

    assert Enum.all?(r.rack_codes["f2"], fn {_, _, program} ->
             program == TartarusWarehouse.Program.Merge
           end)

    # The robot starts a block at least a round trip to a rack after its claim: a Φ node is
    # at least one link of 10 ms from a robot, each way.
    assert Enum.all?(r.history, &(&1.start_us - &1.claimed_us >= 20_000))

    # Without racks the robot starts as it is claimed.
    {_, without} = run_floor([])
    assert without.rack_codes == %{}
    assert Enum.all?(without.history, &(&1.start_us - &1.claimed_us < 20_000))
  end

  test "racks need Φ nodes, and a rack refuses code it cannot load" do
    assert {:error, message} =
             Floor.run(robots: 2, jobs: Jobs.soft_jobs(1, 1, 2000), phi_agents: true)

    assert message =~ "key :phi_agents"

    {:ok, host} = Tartarus.start_host(:"rack_test_#{System.unique_integer([:positive])}")
    {:ok, id} = Tartarus.create_static_agent(host, TartarusWarehouse.Rack, %{rack: "f1"})
    rack = {id, host}

    assert {:ok, {:error, {:no_code, :no_such_program}}} =
             Tartarus.request(rack, {:code, :a, [{"T1", :no_such_program}]}, 5_000)

    assert {:ok, :ok} =
             Tartarus.request(rack, {:code, :a, [{"T1", TartarusWarehouse.Program.Sort}]}, 5_000)

    assert {:ok, [{:a, "T1", TartarusWarehouse.Program.Sort}]} =
             Tartarus.request(rack, :received, 5_000)

    Tartarus.stop_host(host)
  end
end
