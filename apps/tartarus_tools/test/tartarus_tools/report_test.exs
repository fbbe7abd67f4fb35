defmodule TartarusEmu.ReportTest do
  use ExUnit.Case, async: true

  alias TartarusTools.Report

  doctest Report

  setup do
    dir = Path.join(System.tmp_dir!(), "report_test_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    %{dir: dir}
  end

  describe "CSV" do
    test "RFC 4180 quoting" do
      csv =
        Report.to_csv(
          ["a", "b"],
          [["plain", "com,ma"], ["quo\"te", "new\nline"], ["cr\rlf", 1.5], [nil, :atom]]
        )

      assert csv ==
               "a,b\nplain,\"com,ma\"\n\"quo\"\"te\",\"new\nline\"\n\"cr\rlf\",1.5\n,atom\n"

      assert Report.to_csv(["x"], [[1]], line_ending: "\r\n") == "x\r\n1\r\n"
    end

    test "rows must match the header; fields must be scalars" do
      assert_raise ArgumentError,
                   "Report.to_csv/3: expected row 2 to be a list of 2 fields (as many as the header), got: [1]",
                   fn -> Report.to_csv(["a", "b"], [[1, 2], [1]]) end

      assert_raise ArgumentError,
                   ~r/expected fields to be strings, atoms, numbers or nil, got: \{1, 2\}/,
                   fn ->
                     Report.to_csv(["a"], [[{1, 2}]])
                   end
    end

    test "write_csv!/5 creates the directory and adds .csv", %{dir: dir} do
      path = Report.write_csv!(Path.join(dir, "nested"), "hops", ["step", "hops"], [[1, 3]])
      assert path == Path.join([dir, "nested", "hops.csv"])
      assert File.read!(path) == "step,hops\n1,3\n"
      assert Report.write_csv!(dir, "x.csv", ["a"], []) == Path.join(dir, "x.csv")

      assert_raise ArgumentError, ~r/expected a plain name .*got: "..\/evil.csv"/, fn ->
        Report.write_csv!(dir, "../evil", ["a"], [])
      end
    end
  end

  describe "summary" do
    test "writes JSON and Markdown with comparisons", %{dir: dir} do
      summary = %{seed: 7, mean_hops: 3.25, scenario: "lats|where", params: %{p: 0.1}}

      [json, md] =
        Report.write_summary!(dir, summary,
          title: "LATS",
          comparisons: [
            %{metric: "mean hops", ours: 3.25, thesis: 3.9},
            %{metric: "queries", ours: 200, thesis: 200, note: "same workload"}
          ]
        )

      assert Path.basename(json) == "summary.json"
      decoded = Tartarus.JSON.decode!(File.read!(json))
      assert decoded["seed"] == 7
      assert decoded["params"] == %{"p" => 0.1}

      assert [%{"metric" => "mean hops", "ours" => 3.25, "thesis" => 3.9} | _] =
               decoded["comparisons"]

      text = File.read!(md)
      assert text =~ "# LATS\n"
      assert text =~ "| mean_hops | 3.25 |"
      assert text =~ "| params | {\"p\":0.1} |"
      assert text =~ "| scenario | lats\\|where |"
      assert text =~ "| metric | ours | thesis | note |"
      assert text =~ "| mean hops | 3.25 | 3.9 |  |"
      assert text =~ "| queries | 200 | 200 | same workload |"
    end

    test "without comparisons the JSON is the summary and its provenance", %{dir: dir} do
      [json, md] = Report.write_summary!(dir, %{"a" => [1, 2]})
      decoded = Tartarus.JSON.decode!(File.read!(json))
      assert Map.delete(decoded, "provenance") == %{"a" => [1, 2]}

      assert Enum.sort(Map.keys(decoded["provenance"])) ==
               ~w(argv date elixir git_commit git_dirty machine otp)

      assert decoded["provenance"]["elixir"] == System.version()
      assert {:ok, _, 0} = DateTime.from_iso8601(decoded["provenance"]["date"])
      assert decoded["provenance"]["machine"]["schedulers"] == System.schedulers_online()
      text = File.read!(md)
      refute text =~ "Ours vs thesis"
      assert text =~ "## Provenance"
      assert text =~ "| elixir | #{System.version()} |"

      [json, md] = Report.write_summary!(dir, %{"a" => 1}, provenance: false)
      assert Tartarus.JSON.decode!(File.read!(json)) == %{"a" => 1}
      refute File.read!(md) =~ "Provenance"
    end

    test "a long nested value gets a section of its own, not one table cell" do
      description = %{n: 10, median: 12, q1: 9, q3: 15, mean: 12.4, sd: 3.1}

      sweep = %{
        name: "danger",
        runs: 20,
        aggregates: %{"signals" => %{steps: description, events: description}},
        tests: [
          %{a: "signals", alternative: :less, b: "no_signals", metric: :steps, p_value: 0.027},
          %{a: "signals", alternative: :less, b: "no_sharing", metric: :steps, p_value: 0.001}
        ]
      }

      md = Report.summary_markdown(%{seed: 1, sweep: sweep, short: [1, 2]})
      # The key table: short values in their cells, the sweep pointed to.
      assert md =~ "| seed | 1 |\n| short | [1,2] |\n| sweep | see sweep below |\n"
      refute md =~ ~s("aggregates")
      # The sweep: its short keys, then a table per arm (a metric a row), then the tests.
      assert md =~ "\n## sweep\n\n| key | value |\n|---|---|\n"
      assert md =~ "| aggregates | see sweep.aggregates below |\n| name | danger |\n| runs | 20 |\n| tests | see sweep.tests below |\n"
      assert md =~ "\n### sweep.aggregates\n\n#### sweep.aggregates.signals\n\n| key | mean | median | n | q1 | q3 | sd |\n"
      assert md =~ "| events | 12.4 | 12 | 10 | 9 | 15 | 3.1 |\n| steps | 12.4 | 12 | 10 | 9 | 15 | 3.1 |\n"
      assert md =~ "\n### sweep.tests\n\n| a | alternative | b | metric | p_value |\n|---|---|---|---|---|\n"
      assert md =~ "| signals | less | no_signals | steps | 0.027 |\n| signals | less | no_sharing | steps | 0.001 |\n"
      # No line of it is longer than its longest section row needs.
      assert md |> String.split("\n") |> Enum.map(&String.length/1) |> Enum.max() < 120
    end

    test "bad comparisons and clashing keys are refused", %{dir: dir} do
      assert_raise ArgumentError,
                   ~r/expected comparisons %\{metric:, ours:, thesis:\}, got: %\{metric: "x"\}/,
                   fn ->
                     Report.write_summary!(dir, %{}, comparisons: [%{metric: "x"}])
                   end

      assert_raise ArgumentError, ~r/no "comparisons" key/, fn ->
        Report.write_summary!(dir, %{comparisons: 1},
          comparisons: [%{metric: 1, ours: 1, thesis: 1}]
        )
      end
    end
  end

  test "default_out_dir/2" do
    assert Report.default_out_dir(:warehouse, ~U[2018-01-02 03:04:05Z]) ==
             "results/warehouse-20180102-030405"

    assert Report.default_out_dir("x") =~ ~r/\Aresults\/x-\d{8}-\d{6}\z/

    assert_raise ArgumentError, ~r/expected a plain name/, fn -> Report.default_out_dir("a/b") end
  end
end
