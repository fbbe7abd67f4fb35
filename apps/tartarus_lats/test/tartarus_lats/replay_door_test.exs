defmodule TartarusLats.ReplayDoorTest do
  # The real-data replay's door (issue 42): a log that cannot be judged ends the task with
  # one line saying why and a non-zero exit (a Mix.Error), never "pass"; a run without
  # --fingerprints has no fingerprinting anywhere; what the log held that was not replayed
  # (unknown receivers, bad lines with their numbers, a last line without a newline) is in
  # the output and in summary.json.
  use ExUnit.Case, async: false

  @moduletag :tmp_dir

  @devices Path.expand("../fixtures/tetam.dev", __DIR__)
  @log Path.expand("../fixtures/tetam_straight_01_25s.csv", __DIR__)

  setup do
    Mix.shell(Mix.Shell.Process)
    on_exit(fn -> Mix.shell(Mix.Shell.IO) end)
    :ok
  end

  # The fixture's readings (no comment lines), the first `seconds` seconds of them.
  defp readings(seconds \\ 25) do
    lines = @log |> File.read!() |> String.split("\n", trim: true)
    data = Enum.reject(lines, &String.starts_with?(&1, "#"))
    t0 = data |> hd() |> String.split(",") |> hd() |> String.to_float() |> Float.floor()

    Enum.filter(data, fn l ->
      l |> String.split(",") |> hd() |> String.to_float() < t0 + seconds
    end)
  end

  defp write(dir, name, text) do
    path = Path.join(dir, name)
    File.write!(path, text)
    path
  end

  defp task(argv), do: Mix.Tasks.Tartarus.Lats.run(argv)

  # The task must fail with one line naming the track and why, and print no pass.
  defp refused(dir, log, why) do
    message =
      try do
        task(~w(--replay-log #{log} --devices #{@devices} --seeds 1 --queries 1 --out) ++ [dir])
        flunk("the replay of #{log} did not fail")
      rescue
        e in Mix.Error -> e.message
      end

    assert message =~ why, message
    assert message =~ Path.rootname(Path.basename(log)), message
    refute message =~ "\n", message
    refute_received {:mix_shell, :info, ["pass" <> _]}
    refute File.exists?(Path.join(dir, "summary.json"))
    message
  end

  # A short replay through the task; its output lines and summary.json.
  defp replay(dir, log, extra \\ []) do
    out = Path.join(dir, "out")

    task(
      ~w(--replay-log #{log} --devices #{@devices} --seeds 1 --queries 1 --out) ++ [out] ++ extra
    )

    lines = collect([])
    summary = out |> Path.join("summary.json") |> File.read!() |> Tartarus.JSON.decode!()
    {Enum.join(lines, "\n"), summary, out}
  end

  defp collect(acc) do
    receive do
      {:mix_shell, :info, [line]} -> collect([line | acc])
    after
      0 -> Enum.reverse(acc)
    end
  end

  defp track(summary, name), do: summary["summary"]["tracks"][name] || summary["tracks"][name]

  test "an empty log is refused: no valid reading", %{tmp_dir: dir} do
    refused(dir, write(dir, "empty.csv", ""), "no valid reading (0 lines, 0 bad)")
  end

  test "a log of comments only is refused: no valid reading", %{tmp_dir: dir} do
    log = write(dir, "comments.csv", "# a comment\n# another\ntime,receiver,beacon,rssi\n")
    refused(dir, log, "no valid reading")
  end

  test "a log with no true position is refused: nothing to judge against", %{tmp_dir: dir} do
    text =
      readings()
      |> Enum.map_join("\n", fn l -> l |> String.split(",") |> Enum.take(4) |> Enum.join(",") end)

    refused(dir, write(dir, "nopos.csv", text <> "\n"), "no true position")
  end

  test "a log shorter than the warm-up is refused: no second to judge", %{tmp_dir: dir} do
    log = write(dir, "short.csv", Enum.join(readings(3), "\n") <> "\n")
    refused(dir, log, "no second to judge")
  end

  test "a log whose receivers the devices file does not name is refused", %{tmp_dir: dir} do
    text =
      readings(10)
      |> Enum.map_join("\n", fn l ->
        String.replace(l, ~r/^([^,]+),[^,]+,/, "\\1,ffffffffffff,")
      end)

    refused(dir, write(dir, "strangers.csv", text <> "\n"), "ffffffffffff")
  end

  @tag timeout: 120_000
  test "without --fingerprints the fingerprinting baseline is absent from every output",
       %{tmp_dir: dir} do
    log = write(dir, "plain.csv", Enum.join(readings(10), "\n") <> "\n")
    {out, summary, files} = replay(dir, log)
    assert out =~ "plain lats: exact"
    refute out =~ "knn"
    assert out =~ "pass (pre-registered criterion): "
    refute inspect(summary) =~ "knn"
    seconds = File.read!(Path.join(files, "plain_seconds.csv"))
    assert seconds |> String.split("\n") |> hd() == "second,x,y,truth,lats,thesis,strongest"
    queries = File.read!(Path.join(files, "plain_queries.csv"))
    refute queries =~ "knn"
  end

  @tag timeout: 120_000
  test "readings of a receiver not in the devices file are named with their count", %{
    tmp_dir: dir
  } do
    data = readings(10)

    strangers =
      for l <- Enum.take(data, 7),
          do: String.replace(l, ~r/^([^,]+),[^,]+,/, "\\1,0000000000ff,")

    log = write(dir, "unknown.csv", Enum.join(data ++ strangers, "\n") <> "\n")
    {out, summary, _} = replay(dir, log)

    assert out =~
             "unknown input: readings of receivers not in the devices file, not replayed: 0000000000ff (7)"

    assert track(summary, "unknown")["unknown_receivers"] == %{"0000000000ff" => 7}
  end

  @tag timeout: 120_000
  test "bad lines are listed with their numbers and why; a last line cut short is not read",
       %{tmp_dir: dir} do
    data = readings(10)
    # The last line cut in the middle of its RSSI (-87 -> -8): a valid-looking reading.
    [last | _] = Enum.reverse(data)
    cut = String.replace(last, ~r/,(-\d)\d,/, ",\\1,")
    assert cut != last
    lines = Enum.drop(Enum.take(data, 20) ++ ["garbage"] ++ Enum.drop(data, 20), -1)
    log = write(dir, "cut.csv", Enum.join(lines ++ [cut], "\n"))
    n = length(lines) + 1

    {out, summary, _} = replay(dir, log)

    assert out =~ "cut input: 2 bad line(s) of #{n}: line 21: expected time, receiver"
    assert out =~ "line #{n}: last line has no newline (cut short?): not read"
    assert out =~ "cut input: last line (#{n}) has no newline: not read"

    t = track(summary, "cut")
    assert t["log_unterminated_line"] == n
    assert t["log_bad_lines"] == 2

    assert [%{"line" => 21, "why" => "expected" <> _}, %{"line" => ^n, "why" => "last line" <> _}] =
             t["bad_lines"]
  end
end
