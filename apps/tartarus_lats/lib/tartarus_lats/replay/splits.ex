defmodule TartarusLats.Replay.Splits do
  @moduledoc """
  Out-of-sample judging of the real-data replay (issue 42; the protocol is registered in
  docs/lats.md, "Out of sample"): a grid of zone configurations is run on every track
  (`TartarusLats.Replay.Experiment`, seeds pooled), and for every split of the tracks into
  two tuning tracks and the others, the configuration that does best on the tuning tracks
  (`choose/3`) is judged on the others. Nothing is judged on a track it was chosen on.

      mix run -e 'TartarusLats.Replay.Splits.main(["DATA_DIR", "CALIBRATION", "OUT.json"])'

  runs the registered grid (`grid/0`) on `DATA_DIR/tracks` with `DATA_DIR/tetam.dev`, the
  calibration file and `DATA_DIR/fingerprints/set_1`, and writes every configuration's
  per-track figures and the splits to `OUT.json`.
  """

  alias TartarusLats.Replay.Experiment

  @doc """
  The registered grid: `margin_db` 2, 3, 4 x `dwell` 1, 2, 3 x `fast_db` 6, 12, every other
  option at the replay's defaults (`TartarusLats.Replay.schema/0`), in this order.
  """
  @spec grid() :: [keyword()]
  def grid do
    base = TartarusLats.Replay.schema()[:zone][:default]

    for m <- [2.0, 3.0, 4.0], d <- [1, 2, 3], f <- [6.0, 12.0] do
      base |> Keyword.merge(margin_db: m, dwell: d, fast_db: f)
    end
  end

  @doc """
  How many of the criterion's comparisons a track's figures hold (`pass` of a track in
  `TartarusLats.Replay.Experiment`'s summary): LATS at least the strongest receiver on
  exact and adjacent rate and Where is X, and a mean Trace edit distance at most its.
  """
  @spec held(map()) :: non_neg_integer()
  def held(track), do: track.pass |> Map.values() |> Enum.count(& &1)

  @doc """
  The configuration chosen on `tuning` (track names) from `results`, `[{config,
  %{track => figures}}]` in grid order: the most comparisons held over the tuning tracks,
  then the higher mean exact rate of LATS on them, then the higher mean adjacent rate, then
  the first in grid order. Returns `{index, config}`.

      iex> t = fn held, exact -> %{pass: %{a: held > 0, b: held > 1}, lats: %{exact: exact, adjacent: 1.0}} end
      iex> results = [{[m: 1], %{"x" => t.(1, 0.5), "y" => t.(1, 0.5)}}, {[m: 2], %{"x" => t.(2, 0.4), "y" => t.(1, 0.4)}}]
      iex> TartarusLats.Replay.Splits.choose(results, ["x", "y"], [])
      {1, [m: 2]}
  """
  @spec choose([{keyword(), map()}], [String.t()], keyword()) :: {non_neg_integer(), keyword()}
  def choose(results, tuning, _opts \\ []) do
    {{cfg, _}, i} =
      results
      |> Enum.with_index()
      |> Enum.max_by(fn {{_cfg, tracks}, i} ->
        ts = Enum.map(tuning, &Map.fetch!(tracks, &1))
        mean = fn f -> Enum.sum(Enum.map(ts, f)) / length(ts) end
        {Enum.sum(Enum.map(ts, &held/1)), mean.(& &1.lats.exact), mean.(& &1.lats.adjacent), -i}
      end)

    {i, cfg}
  end

  @doc """
  Every split of `names` (sorted) into two tuning tracks and the rest, with the
  configuration chosen on the tuning ones and its figures in sample (tuning tracks) and
  out of sample (the others): `[%{tuning:, judged:, chosen:, config:, in_sample:,
  out_of_sample:}]`, the figures `%{track => figures}`.
  """
  @spec splits([{keyword(), map()}], [String.t()]) :: [map()]
  def splits(results, names) do
    names = Enum.sort(names)

    for [a, b] <- pairs(names) do
      tuning = [a, b]
      judged = names -- tuning
      {i, cfg} = choose(results, tuning)
      {_, tracks} = Enum.at(results, i)

      %{
        tuning: tuning,
        judged: judged,
        chosen: i,
        config: cfg,
        in_sample: Map.take(tracks, tuning),
        out_of_sample: Map.take(tracks, judged)
      }
    end
  end

  defp pairs([]), do: []
  defp pairs([x | rest]), do: Enum.map(rest, &[x, &1]) ++ pairs(rest)

  @doc "Runs the registered grid and the splits (see the moduledoc); `argv` is `[data_dir, calibration, out_json]`."
  @spec main([String.t()]) :: :ok
  def main([data, calibration, out]) do
    tracks = Path.join(data, "tracks")
    logs = tracks |> File.ls!() |> Enum.filter(&String.ends_with?(&1, ".mbd")) |> Enum.sort()
    logs = Enum.map(logs, &Path.join(tracks, &1))

    common = [
      logs: logs,
      devices: Path.join(data, "tetam.dev"),
      calibration: calibration,
      fingerprints: Path.join(data, "fingerprints/set_1"),
      out: false,
      quiet: true
    ]

    results =
      for {cfg, i} <- Enum.with_index(grid()) do
        {:ok, %{summary: s}} = Experiment.run(common ++ [replay: [zone: cfg, thesis: i == 0]])
        IO.puts(:stderr, "configuration #{i + 1} of #{length(grid())} done")
        {cfg, s.tracks}
      end

    names = results |> hd() |> elem(1) |> Map.keys()
    splits = splits(results, names)

    json = %{
      grid: Enum.map(results, fn {cfg, tracks} -> %{config: Map.new(cfg), tracks: tracks} end),
      splits: Enum.map(splits, &Map.update!(&1, :config, fn c -> Map.new(c) end))
    }

    File.write!(out, Tartarus.JSON.encode!(json))
    :ok
  end
end
