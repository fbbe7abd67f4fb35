defmodule TartarusImmune.SelectTest do
  use ExUnit.Case, async: false

  import Tartarus.TestSupport
  alias TartarusImmune.Select

  @tag :tmp_dir
  test "the sharing experiment reports both arms and writes its files", %{tmp_dir: dir} do
    {:ok, r} =
      Select.run(
        experiment: :sharing,
        set: :p1,
        nodes: 4,
        steps: 25,
        hold: 5,
        quiet: true,
        out: dir
      )

    s = r.summary
    assert s.experiment == "sharing"
    assert Map.keys(s.arms) |> Enum.sort() == ["no_sharing", "sharing"]
    assert Map.keys(s.convergence_steps) |> Enum.sort() == ["no_sharing", "sharing"]
    assert s.arms["no_sharing"].migrations_mean == 0.0
    assert s.arms["sharing"].migrations_mean > 0
    assert %{"p1" => _} = s.winners
    assert %{"p1" => acc} = s.test_accuracy
    assert acc >= 0 and acc <= 1

    for f <- ~w(runs.csv population_sharing_p1.svg population_no_sharing_p1.csv summary.json),
        do: assert(File.exists?(Path.join(dir, f)), f)

    json = File.read!(Path.join(dir, "summary.json"))
    assert json =~ ~s("convergence_steps") and json =~ ~s("test_regret")
  end

  @tag :tmp_dir
  test "two seeds: the sweep's aggregates, box plots and the test of sharing", %{tmp_dir: dir} do
    opts = [experiment: :sharing, set: :p1, nodes: 4, steps: 25, hold: 5, quiet: true]
    {:ok, r} = Select.run(opts ++ [seeds: 2, out: dir])
    sweep = r.summary.sweep
    assert sweep.arms == ["sharing p1", "no_sharing p1"]
    assert sweep.runs == 4
    steps = r.summary.arms["sharing"].convergence_steps
    assert sweep.aggregates["sharing p1"].steps.n == 2
    assert [%{a: "sharing p1", b: "no_sharing p1", metric: :steps, method: :exact}] = sweep.tests
    assert File.exists?(Path.join(dir, "steps.svg"))

    [header | rows] =
      dir |> Path.join("runs.csv") |> File.read!() |> String.split("\n", trim: true)

    assert header =~ ~r/^arm,set,seed,winner,/

    assert Enum.map(rows, &(&1 |> String.split(",") |> Enum.take(3))) ==
             [~w(sharing p1 1), ~w(no_sharing p1 1), ~w(sharing p1 2), ~w(no_sharing p1 2)]

    # the same numbers one run at a time (seed 1 alone)
    {:ok, one} = Select.run(opts ++ [out: false])
    assert hd(steps) == hd(one.summary.arms["sharing"].convergence_steps)
  end

  # A few seconds alone; over ExUnit's 60 s when other work loads the machine.
  @tag timeout: 300_000
  test "on the dashboard: the run going now, a row per host; the same results as without it" do
    {:ok, l} = :gen_tcp.listen(0, [])
    {:ok, port} = :inet.port(l)
    :gen_tcp.close(l)
    # hold: 200, so the run goes all 200 rounds: with its costs memoized by earlier tests
    # it could otherwise end before the first look at the panel
    opts = [
      experiment: :sharing,
      set: :p1,
      nodes: 4,
      steps: 200,
      hold: 200,
      quiet: true,
      out: false
    ]

    me = self()

    run =
      Task.async(fn ->
        r = Select.run(opts ++ [dashboard: [port: port, token: "immune-panel-test"]])
        send(me, :done)
        r
      end)

    url = "http://127.0.0.1:#{port}/api/panels"

    panel =
      eventually(
        fn ->
          with {:ok, 200, body} <- TartarusDashboard.http_get(url, 5_000),
               [%{"rows" => [_, _, _, _]} = p] <- Tartarus.JSON.decode!(body)["panels"],
               do: p,
               else: (_ -> nil)
        end,
        60_000
      )

    assert panel["title"] =~ "Immune selection (thesis ch. 6): sharing: "
    assert panel["text"] =~ ~r/Round \d+, data set p1: live iPkts /

    assert Enum.all?(
             panel["rows"],
             &match?([_, p, q, _] when is_integer(p) and is_integer(q), &1)
           )

    assert_receive :done, 120_000
    {:ok, with_dash} = Task.await(run)
    {:ok, without} = Select.run(opts)
    assert with_dash.summary.convergence_steps == without.summary.convergence_steps
    assert with_dash.summary.winners == without.summary.winners
    # the dashboard went with the experiment
    assert {:error, _} = TartarusDashboard.http_get(url, 2_000)
  end

  # About 1.5 minutes (tag :long: TARTARUS_TESTS=quick leaves it out). The issue's target;
  # met (10 of 10) since a performance score is the solution's own cost over the
  # instance's scale (Params :score_ref), see docs/immune.md.
  @tag :long
  @tag timeout: 900_000
  test "table6_2 over seeds 1-10 picks IS, QS, IS, QS in at least 9 seeds" do
    {:ok, r} = Select.run(experiment: :table6_2, seeds: 10, quiet: true, out: false)
    assert r.summary.seeds_matching_thesis >= 9
    assert r.summary.winners == %{"p1" => "IS", "p2" => "QS", "p3" => "IS", "p4" => "QS"}
  end

  test "an unknown experiment is refused with the key's name" do
    assert {:error, msg} = Select.run(experiment: :nope)
    assert msg =~ ":experiment"
  end
end
