defmodule TartarusEmu.ScenarioTest do
  use ExUnit.Case, async: true

  alias TartarusEmu.{Energy, Scenario, Walk}
  alias TartarusTools.Series

  doctest TartarusEmu.Walk

  defp tmp do
    dir = Path.join(System.tmp_dir!(), "emu_scenario_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    dir
  end

  defp walk(opts) do
    base = [topology: "grid", hosts: 16, agents: 6, steps: 15, quiet: true, out: false]
    {:ok, result} = Scenario.run(Walk, Keyword.merge(base, opts))
    result
  end

  test "same seed, same series (with link dynamics and loss); another seed differs" do
    opts = [seed: 42, p: 0.15, loss: 0.2, strategy: :conscientious]
    a = walk(opts)
    b = walk(opts)
    c = walk(Keyword.put(opts, :seed, 43))

    assert a.series == b.series
    assert Series.to_rows(a.series) != []
    refute a.series == c.series

    assert Map.take(a.summary, [:migrations, :failed_moves, :bytes, :coverage]) ==
             Map.take(b.summary, [:migrations, :failed_moves, :bytes, :coverage])

    # Dynamics and loss did something.
    assert a.summary.failed_moves > 0
    assert Enum.any?(Series.points(a.series, :down_nodes), fn {_, d} -> d > 0 end)
  end

  test "each agent makes one move per step; migrations agree with the log" do
    %{summary: s, series: series} = walk(seed: 1, agents: 5, steps: 10)
    assert Enum.all?(Series.points(series, :migrations), fn {_, m} -> m == 5 end)
    assert s.migrations == 50
    assert s.messages == 50
    assert s.lost_reports == 0
    assert s.failed_moves == 0
  end

  test "until_covered stops once every host was visited" do
    %{summary: s, series: series} =
      walk(
        seed: 3,
        topology: "ring",
        hosts: 8,
        agents: 2,
        steps: 500,
        until_covered: true,
        strategy: :conscientious
      )

    assert s.coverage == 1.0
    assert s.steps == s.covered_at_step
    assert s.steps < 500
    assert {_, 1.0} = List.last(Series.points(series, :coverage))
  end

  test "wall_ms is the run's real time, the pauses of step_ms included; steps_ms the steps' own" do
    %{summary: s} = walk(seed: 3, steps: 4, step_ms: 150)
    # Three pauses of 150 ms lie between the first step's start and the last step's end.
    assert s.wall_ms >= 3 * 150
    assert s.steps_ms <= s.wall_ms - 3 * 150
    assert s.run_ms >= s.wall_ms
  end

  test "writes CSVs, valid SVG plots, summary.md and summary.json; energy is per message and byte" do
    dir = tmp()
    %{summary: s, files: files} = walk(seed: 7, out: dir, keep_events: true)

    names = Enum.map(files, &Path.basename/1)

    for f <- ~w(series.csv coverage.csv migrations.csv coverage.svg migrations.svg walk.svg
                log_steps.csv log_hosts.csv log_links.csv log_events.csv summary.md summary.json),
        do: assert(f in names, f)

    for svg <- Enum.filter(files, &String.ends_with?(&1, ".svg")) do
      {doc, _} = :xmerl_scan.file(String.to_charlist(svg), quiet: true)
      assert elem(doc, 0) == :xmlElement
      assert elem(doc, 1) == :svg
    end

    json = dir |> Path.join("summary.json") |> File.read!() |> Tartarus.JSON.decode!()

    for k <- ~w(hosts agents steps mode migrations migrations_per_s messages bytes wall_ms
                coverage energy_mj seed topology),
        do: assert(Map.has_key?(json, k), k)

    assert json["seed"] == 7
    assert File.read!(Path.join(dir, "summary.md")) =~ "| migrations |"

    # Energy: every hand-off on a link costs per_message + bytes * per_byte.
    [_ | rows] =
      dir |> Path.join("log_links.csv") |> File.read!() |> String.split("\n", trim: true)

    {msgs, bytes} =
      Enum.reduce(rows, {0, 0}, fn row, {m, b} ->
        [_, _, mm, bb] = String.split(row, ",")
        {m + String.to_integer(mm), b + String.to_integer(bb)}
      end)

    assert msgs == s.migrations
    assert bytes == s.bytes
    assert_in_delta s.energy_mj, Energy.cost(%{messages: msgs, bytes: bytes}), 0.01
    assert_in_delta s.energy_mj, msgs * 0.2 + bytes * 0.002, 0.01
  end

  test "setup errors come back from run/2" do
    assert {:error, msg} = Scenario.run(Walk, topology: "moebius", quiet: true, out: false)
    assert msg =~ "invalid topology"
    assert {:error, msg} = Scenario.run(Walk, strategy: :teleport, quiet: true, out: false)
    assert msg =~ "strategy"
  end

  test "runner options are validated" do
    assert {:error, msg} = Scenario.run(Walk, steps: 0)
    assert msg =~ "for key :steps"
  end
end
