defmodule TartarusImmune.ExperimentTest do
  use ExUnit.Case, async: false
  alias TartarusEmu.Scenario
  alias TartarusImmune.{Convergence, Experiment}
  doctest TartarusImmune.Convergence

  @opts [set: :p3, nodes: 6, steps: 120, quiet: true, test: 10, train: 30]

  @tag :tmp_dir
  test "a run learns P3's best (IS), writes its files, and the same seed gives the same numbers",
       %{tmp_dir: dir} do
    {:ok, a} = Scenario.run(Experiment, [seed: 3, out: dir] ++ @opts)
    {:ok, b} = Scenario.run(Experiment, [seed: 3, out: false] ++ @opts)
    {:ok, c} = Scenario.run(Experiment, [seed: 4, out: false] ++ @opts)
    drop = &Map.drop(&1, [:setup_ms, :run_ms])
    assert drop.(a.summary) == drop.(b.summary)
    assert a.series == b.series
    refute a.series == c.series
    assert a.summary.winner == "IS" and a.summary.known_best == "IS"
    assert a.summary.converged and a.summary.test_accuracy == 1.0, inspect(a.summary)
    # the learning curve: population per solution per step, and the convergence rule on it
    pops =
      for k <- 1..a.summary.steps_run do
        {k,
         Map.new(~w(QS IS ShS SelS), fn n ->
           {n, a.series |> TartarusTools.Series.points(n) |> Map.new() |> Map.get(k, 0)}
         end)}
      end

    assert Convergence.of_series(pops, share: 0.9, hold: 30) ==
             {a.summary.convergence_step, "IS"}

    for f <- ~w(series.csv IS.csv IS.svg summary.json summary.md),
        do: assert(File.exists?(Path.join(dir, f)), f)

    # the log server's count: migrations plus executions, at the end of the run and (fewer)
    # at the convergence step; the wider count adds clones and deaths
    s = a.summary
    execs = s.executed |> Map.values() |> Enum.sum()
    assert s.events_run == s.migrations + execs
    assert s.events_all_run == s.events_run + s.clones + s.deaths + s.expired
    assert s.convergence_events > 0 and s.convergence_events < s.events_run
    assert s.convergence_events_all >= s.convergence_events
  end

  test "without sharing no iPkt migrates" do
    {:ok, r} =
      Scenario.run(
        Experiment,
        [seed: 1, out: false, sharing: false] ++ Keyword.put(@opts, :steps, 12)
      )

    assert r.summary.migrations == 0 and r.summary.clones > 0
    # nothing travels, so the log server counts only executions
    assert r.summary.events_run == r.summary.executed |> Map.values() |> Enum.sum()
  end

  test "a dynamic network: hosts break off and reconnect, the run still learns" do
    {:ok, r} =
      Scenario.run(
        Experiment,
        [seed: 2, out: false, dynamic: 0.5] ++ Keyword.put(@opts, :steps, 15)
      )

    assert r.summary.link_toggles > 10
    assert r.summary.population["IS"] > 0
  end

  test "options are validated" do
    assert {:error, msg} = Scenario.run(Experiment, seed: 1, out: false, quiet: true, eta: 2)
    assert msg =~ ":eta"
  end
end
