defmodule TartarusEmu.SweepTest do
  use ExUnit.Case, async: true

  alias TartarusEmu.{Sweep, Walk}
  alias Tartarus.JSON
  alias TartarusTools.Report

  doctest Sweep

  defp tmp do
    dir = Path.join(System.tmp_dir!(), "emu_sweep_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    dir
  end

  # Two arms of random walks on a ring: many agents cover it sooner than one.
  defp spec(extra \\ []) do
    Map.merge(
      %{
        name: "walks",
        arms: [{"many", [agents: 6]}, {"one", [agents: 1]}],
        seeds: 1..6,
        scenario: Walk,
        base: [topology: "ring", hosts: 12, steps: 400, until_covered: true],
        metrics: [steps: :steps, migrations: :migrations],
        tests: [{"many", :less, "one", :steps}]
      },
      Map.new(extra)
    )
  end

  test "every (arm, seed) runs once, in the declared order, with the scenario's own numbers" do
    {:ok, r} = Sweep.run(spec(), out: false, quiet: true)

    assert Enum.map(r.runs, &{&1.arm, &1.seed}) ==
             for(s <- 1..6, a <- ["many", "one"], do: {a, s})

    {:ok, alone} =
      TartarusEmu.Scenario.run(Walk,
        topology: "ring",
        hosts: 12,
        steps: 400,
        until_covered: true,
        agents: 1,
        seed: 4,
        out: false,
        quiet: true
      )

    run = Enum.find(r.runs, &(&1.arm == "one" and &1.seed == 4))
    assert run.summary.steps == alone.summary.steps
    assert run.summary.migrations == alone.summary.migrations
    assert run.data == alone.series
  end

  test "results do not depend on how many runs go at once" do
    {:ok, one} = Sweep.run(spec(), out: false, quiet: true, concurrency: 1)
    {:ok, four} = Sweep.run(spec(), out: false, quiet: true, concurrency: 4)
    strip = fn r -> Enum.map(r.runs, &Map.take(&1, [:arm, :seed, :data])) end
    assert strip.(one) == strip.(four)
    assert one.aggregates == four.aggregates
    assert one.tests == four.tests
  end

  test "aggregates per arm, the test between arms, and the files" do
    dir = tmp()

    {:ok, r} =
      Sweep.run(spec(order: :arm_major, subtitle: "ring, 12 hosts"), out: dir, quiet: true)

    steps = fn arm -> for run <- r.runs, run.arm == arm, do: run.summary.steps end

    assert r.aggregates["one"].steps == TartarusTools.Stats.describe(steps.("one"))
    assert r.aggregates["many"].steps.n == 6
    [test] = r.tests
    assert test.a == "many" and test.metric == :steps and test.method == :exact
    assert test.p_value < 0.05

    assert test.p_value ==
             TartarusTools.Stats.mann_whitney(steps.("many"), steps.("one"), alternative: :less).p_value

    assert Enum.sort(Enum.map(r.files, &Path.basename/1)) ==
             ~w(migrations.svg runs.csv steps.svg summary.json summary.md)

    [header | rows] =
      dir |> Path.join("runs.csv") |> File.read!() |> String.split("\n", trim: true)

    assert header == "arm,seed,steps,migrations"
    assert length(rows) == 12
    assert hd(rows) =~ ~r/^many,1,\d+,\d+$/

    json = dir |> Path.join("summary.json") |> File.read!() |> JSON.decode!()
    assert json["sweep"]["runs"] == 12
    assert json["sweep"]["arms"] == ["many", "one"]

    assert json["sweep"]["aggregates"]["one"]["steps"]["median"] ==
             r.aggregates["one"].steps.median

    assert json["sweep"]["aggregates"]["one"]["steps"]["median_mid"] ==
             r.aggregates["one"].steps.median_mid

    # steps.svg: a box per arm, its median line at the arm's conventional median (the
    # aggregates' median_mid, six runs: the mean of the two middle ones), every run's steps
    # as a dot, the seeds in the subtitle.
    svg = File.read!(Path.join(dir, "steps.svg"))

    medians =
      Regex.scan(~r/<g class="median" data-value="([^"]+)">/, svg, capture: :all_but_first)

    assert Enum.map(medians, fn [v] -> elem(Float.parse(v), 0) end) ==
             for(arm <- ["many", "one"], do: r.aggregates[arm].steps.median_mid * 1.0)

    for arm <- ["many", "one"] do
      sorted = Enum.sort(steps.(arm))
      assert r.aggregates[arm].steps.median_mid == (Enum.at(sorted, 2) + Enum.at(sorted, 3)) / 2
    end

    dots =
      Regex.scan(~r/<circle class="sample"[^>]*data-value="(\d+)"/, svg, capture: :all_but_first)

    assert Enum.map(dots, fn [v] -> String.to_integer(v) end) ==
             Enum.sort(steps.("many")) ++ Enum.sort(steps.("one"))

    assert svg =~ "ring, 12 hosts; seeds 1-6"
  end

  test "a line per finished run; the experiment's own summary, rows and files" do
    {:ok, device} = StringIO.open("")

    spec =
      spec(
        seeds: [7, 8],
        summary: fn r ->
          %{fastest: r.runs |> Enum.min_by(& &1.summary.steps) |> Map.get(:arm)}
        end,
        csv: {["arm", "seed", "hosts"], fn run -> [[run.arm, run.seed, run.summary.hosts]] end},
        write: fn dir, r -> [Report.write_csv!(dir, "extra", ["n"], [[length(r.runs)]])] end
      )

    dir = tmp()
    {:ok, r} = Sweep.run(spec, out: dir, progress_device: device, concurrency: 1)
    {_, printed} = StringIO.contents(device)
    lines = String.split(printed, "\n", trim: true)
    assert length(lines) == 4

    assert Enum.all?(
             lines,
             &(&1 =~
                 ~r/^walks \[\d\/4\] (many|one) seed [78] \(\d+\.\d s\)  elapsed \d+:\d\d  ETA \d+:\d\d$/)
           )

    assert r.summary.fastest == "many"
    assert File.read!(Path.join(dir, "runs.csv")) =~ "arm,seed,hosts\nmany,7,12\n"
    assert File.exists?(Path.join(dir, "extra.csv"))
  end

  test "report: summary.json and summary.md show what the spec says, the result keeps all" do
    spec = %{
      name: "rep",
      title: "Report",
      arms: [{"a", [k: 2]}],
      seeds: [1, 2],
      run: fn arm, seed -> %{x: seed * arm.opts[:k], trace: [seed, seed]} end,
      metrics: [x: :x],
      summary: fn r ->
        %{total: r.runs |> Enum.map(& &1.summary.x) |> Enum.sum(), bulky: [1, 2]}
      end,
      report: fn s ->
        [
          summary: Map.delete(s, :bulky),
          comparisons: [%{metric: "total", ours: s.total, thesis: 5}],
          markdown: "## Runs\n\n#{length(s.bulky)} of them\n"
        ]
      end
    }

    dir = tmp()
    {:ok, r} = Sweep.run(spec, out: dir, quiet: true)
    assert r.summary.bulky == [1, 2] and r.summary.total == 6
    json = dir |> Path.join("summary.json") |> File.read!() |> JSON.decode!()
    refute Map.has_key?(json, "bulky")
    assert json["total"] == 6 and json["sweep"]["runs"] == 2
    assert json["comparisons"] == [%{"metric" => "total", "ours" => 6, "thesis" => 5}]
    md = File.read!(Path.join(dir, "summary.md"))
    assert md =~ ~r/^# Report\n/
    assert md =~ "| total | 6 | 5 |"
    assert md =~ "\n## Runs\n\n2 of them\n\n## Provenance\n"
    refute md =~ "bulky"
  end

  test "a run function returning a summary; bad specs are refused with a message" do
    run = fn arm, seed -> %{x: seed * arm.opts[:k]} end

    {:ok, r} =
      Sweep.run(%{name: "f", arms: [{"a", [k: 2]}], seeds: [1, 2], run: run, metrics: [x: :x]},
        out: false,
        quiet: true
      )

    assert Enum.map(r.runs, & &1.summary.x) == [2, 4]
    assert r.aggregates["a"].x.mean == 3.0

    assert {:error, "Sweep: expected :name" <> _} =
             Sweep.run(%{name: "a/b", arms: [{"a", []}], seeds: [1], run: run})

    assert {:error, "Sweep: expected arm names" <> _} =
             Sweep.run(%{name: "a", arms: [{"a", []}, {"a", []}], seeds: [1], run: run})

    assert {:error, "Sweep: expected tests" <> _} =
             Sweep.run(%{
               name: "a",
               arms: [{"a", []}],
               seeds: [1],
               run: run,
               metrics: [x: :x],
               tests: [{"a", :less, "b", :x}]
             })
  end
end
