defmodule TartarusLats.ReplayTest do
  # Recorded HM-10 serial output fed back to the nodes (`--record`, `--replay`): the text
  # goes through the HM-10 parser on its way to the receivers, and a recording replayed with
  # the seed it was made with reproduces the run.
  use ExUnit.Case, async: false
  doctest TartarusLats.HM10.Recording

  alias TartarusLats.{Experiment, HM10}

  @fixture Path.expand("../fixtures/lats_10_nodes_seed_4.hm10.gz", __DIR__)
  @small [nodes: 10, minutes: 3, queries: 3, quiet: true, out: false]
  # Keys that measure time or describe the input, not the outcome.
  @not_outcome [:setup_ms, :run_ms, :median_query_ms, :input] ++
                 [:replay_records, :replay_bad_records, :replay_garbage_bytes]

  defp outcome(summary), do: Map.drop(summary, @not_outcome)

  @tag timeout: 120_000
  test "same seed, same summary (virtual mode); latencies are measured on one clock" do
    {:ok, a} = Experiment.run(@small ++ [seed: 2])
    {:ok, b} = Experiment.run(@small ++ [seed: 2])
    assert outcome(a.summary) == outcome(b.summary)
    assert a.summary.median_query_ms > 0
    # --nodes is rounded to whole rows; the summary says what was built.
    {:ok, c} = Experiment.run(Keyword.put(@small, :nodes, 15) ++ [seed: 2])
    assert c.summary.nodes == 20
  end

  @tag :tmp_dir
  @tag timeout: 120_000
  test "a run recorded and replayed gives the same summary", %{tmp_dir: dir} do
    path = Path.join(dir, "run.hm10")
    {:ok, recorded} = Experiment.run(@small ++ [seed: 6, record: path])
    {:ok, replayed} = Experiment.run(@small ++ [seed: 6, replay: path])

    assert recorded.summary.input == "simulated"
    assert replayed.summary.input == "replay"
    assert replayed.summary.replay_records > 1_000
    assert replayed.summary.replay_bad_records == 0
    assert outcome(replayed.summary) == outcome(recorded.summary)
  end

  # The fixture was made by the simulator:
  #   mix tartarus.lats --nodes 10 --minutes 3 --queries 3 --seed 4 --noise-db 2 \
  #     --record apps/tartarus_lats/test/fixtures/lats_10_nodes_seed_4.hm10.gz
  # If the world or the radio model changes on purpose, make it again with that command.
  @tag timeout: 120_000
  test "the recorded fixture replays end to end: every record parsed, the simulated run's answers" do
    # Made at 2 dB of noise: the simulated run it is compared with must have that noise.
    {:ok, replayed} = Experiment.run(@small ++ [seed: 4, noise_db: 2.0, replay: @fixture])
    {:ok, simulated} = Experiment.run(@small ++ [seed: 4, noise_db: 2.0])

    s = replayed.summary
    assert s.replay_records == 8_553
    assert s.replay_bad_records == 0 and s.replay_garbage_bytes == 0
    assert s.queries == 3 and s.correct == 3
    assert outcome(s) == outcome(simulated.summary)
  end

  @tag :tmp_dir
  @tag timeout: 120_000
  test "junk and damaged records on a node's line are counted, the run goes on", %{tmp_dir: dir} do
    {:ok, recording} = HM10.Recording.read(@fixture)
    bad = String.replace(recording[130]["p1"] || "", "OK+DISC:4C", "OK+DISC:ZZ", global: false)

    text =
      HM10.Recording.header() <>
        Enum.map_join(Enum.sort(recording), fn {t, nodes} ->
          Enum.map_join(Enum.sort(nodes), fn
            {"p1", _serial} when t == 130 -> HM10.Recording.line(t, "p1", "\x00noise" <> bad)
            {node, serial} -> HM10.Recording.line(t, node, serial)
          end)
        end)

    path = Path.join(dir, "damaged.hm10")
    File.write!(path, text)
    {:ok, replayed} = Experiment.run(@small ++ [seed: 4, replay: path])
    assert replayed.summary.replay_garbage_bytes >= 6
    assert replayed.summary.queries == 3
  end

  @tag :tmp_dir
  test "a malformed recording is refused with its line; unknown nodes are named", %{tmp_dir: dir} do
    path = Path.join(dir, "bad.hm10")
    File.write!(path, HM10.Recording.header() <> "1 p1 OK+DISIS\nnot a line\n")
    assert {:error, message} = Experiment.run(@small ++ [seed: 1, replay: path])
    assert message =~ "bad.hm10:3: expected SECOND NODE SERIAL"

    File.write!(path, HM10.Recording.header() <> "1 p1 OK+DISIS\\q\n")
    assert {:error, message} = HM10.Recording.read(path)
    assert message =~ "bad.hm10:2: bad escape"

    File.write!(path, HM10.Recording.header() <> "1 hall OK+DISISOK+DISCE\n")

    assert {:error, message} = Experiment.run(@small ++ [seed: 1, replay: path])
    assert message =~ "names nodes a building of 10 nodes does not have: hall"

    assert {:error, message} = Experiment.run(@small ++ [seed: 1, replay: "/nonexistent.hm10"])
    assert message =~ "no such file"
  end

  test "escaping keeps every byte" do
    bytes = for(b <- 0..255, into: "", do: <<b>>) <> "\\r\\n"
    line = HM10.Recording.line(1, "p1", bytes)
    assert [_, _, escaped] = String.split(String.trim_trailing(line, "\n"), " ", parts: 3)
    refute escaped =~ "\n"
    path = Path.join(System.tmp_dir!(), "escape_#{System.unique_integer([:positive])}.hm10")
    File.write!(path, line)
    assert {:ok, %{1 => %{"p1" => ^bytes}}} = HM10.Recording.read(path)
    File.rm(path)
  end
end
