defmodule TartarusLats.Replay.Judge do
  @moduledoc """
  The truth, the two centralized baselines and the measures of a real-data replay
  (`TartarusLats.Replay`; the rules are in docs/lats.md, "LATS on real BLE recordings").
  Pure functions.

    * **truth** (`truth/3`): a second's true zone is the receiver nearest the beacon's true
      position in the plane (`x, y`; the last position logged in that second, or the one
      before when a second has none);
    * **strongest** (`strongest/3`): the centralized strongest-receiver rule: every second,
      the receiver with the highest mean of the (calibrated) samples it heard in the last
      `window` seconds, the same window as the nodes' trackers; a second where no receiver
      heard anything keeps the last decision;
    * **fingerprinting** (`knn/4`): the centralized k-nearest-neighbours locator: the
      vector of every receiver's mean raw RSSI over the same window (a receiver that heard
      nothing counts -100 dBm) against the reference points' vectors (`fingerprints/2`),
      the mean position of the `k` nearest points in signal space, then the receiver
      nearest that position;
    * **rates** (`rates/4`): exact (decision = truth), adjacent (decision = truth or a
      neighbour of it), zone changes made and true zone changes, over the judged seconds;
    * **queries**: a Where is X answer is judged by `TartarusLats.Judge.correct?/4` on the
      truth's stays (`stays/1`): true at some second of the 15 s before its release; a
      Trace's zone sequence is compared with the truth's up to the release, both with
      repeats merged (`merge/1`), by edit distance (`edit_distance/2`).
  """

  alias TartarusLats.Building

  @typedoc "Per second (1, 2, ...) a node, or nil (no decision)."
  @type decisions :: %{pos_integer() => atom() | nil}

  @doc """
  The true zone of every second from 1 to `last`: `%{second => node}` (see the moduledoc).
  `positions` is `%{second => {x, y}}`; seconds before the first position have none.
  """
  @spec truth(Building.t(), %{pos_integer() => {number(), number()}}, pos_integer()) ::
          decisions()
  def truth(building, positions, last) do
    {acc, _} =
      Enum.reduce(1..last//1, {%{}, nil}, fn s, {acc, prev} ->
        pos = Map.get(positions, s, prev)
        {if(pos, do: Map.put(acc, s, nearest(building, pos)), else: acc), pos}
      end)

    acc
  end

  @doc "The node nearest a point in the plane (ties: the first in node order)."
  @spec nearest(Building.t(), {number(), number()}) :: atom()
  def nearest(building, {x, y}) do
    Enum.min_by(Building.nodes(building), fn n ->
      {nx, ny, _} = Building.position(building, n)
      (nx - x) ** 2 + (ny - y) ** 2
    end)
  end

  @doc """
  The strongest-receiver decisions for seconds 1..`last` from the per-second readings of
  one beacon, `%{second => %{node => rssi}}` (see the moduledoc).

      iex> feed = %{1 => %{a: -70, b: -80}, 2 => %{b: -50}, 3 => %{}}
      iex> TartarusLats.Replay.Judge.strongest(feed, 3, 1)
      %{1 => :a, 2 => :b, 3 => :b}
      iex> TartarusLats.Replay.Judge.strongest(feed, 3, 2)
      %{1 => :a, 2 => :b, 3 => :b}
  """
  @spec strongest(%{pos_integer() => %{atom() => number()}}, pos_integer(), pos_integer()) ::
          decisions()
  def strongest(feed, last, window) do
    decide(feed, last, window, fn means ->
      if means == %{}, do: nil, else: means |> Enum.sort() |> Enum.max_by(&elem(&1, 1)) |> elem(0)
    end)
  end

  # Per second, the mean of each node's samples heard in the window, given to `pick`; a nil
  # pick keeps the last decision.
  defp decide(feed, last, window, pick) do
    {acc, _} =
      Enum.reduce(1..last//1, {%{}, nil}, fn s, {acc, prev} ->
        means = window_means(feed, s, window)
        d = pick.(means) || prev
        {Map.put(acc, s, d), d}
      end)

    acc
  end

  @doc "Per node, the mean of the samples heard in seconds `s - window + 1 .. s`."
  @spec window_means(map(), pos_integer(), pos_integer()) :: %{atom() => float()}
  def window_means(feed, s, window) do
    max(s - window + 1, 1)..s
    |> Enum.flat_map(&Map.to_list(Map.get(feed, &1, %{})))
    |> Enum.group_by(&elem(&1, 0), &elem(&1, 1))
    |> Map.new(fn {n, vs} -> {n, Enum.sum(vs) / length(vs)} end)
  end

  @doc """
  The reference points as fingerprints: `[{{x, y}, %{node => mean rssi}}]` from
  `TartarusLats.Replay.Calibration.points/2`.
  """
  @spec fingerprints([map()]) :: [{{float(), float()}, %{atom() => float()}}]
  def fingerprints(points) do
    points
    |> Enum.group_by(fn %{pos: {x, y, _}} -> {x, y} end)
    |> Enum.sort()
    |> Enum.map(fn {xy, pts} -> {xy, Map.new(pts, &{&1.node, &1.mean})} end)
  end

  @doc """
  The fingerprinting decisions for seconds 1..`last` (see the moduledoc): `raw_feed` is
  `%{second => %{node => raw rssi}}`.
  """
  @spec knn(map(), list(), Building.t(), keyword()) :: decisions()
  def knn(raw_feed, fingerprints, building, opts) do
    last = Keyword.fetch!(opts, :last)
    window = Keyword.fetch!(opts, :window)
    k = Keyword.get(opts, :k, 3)
    nodes = Building.nodes(building)

    decide(raw_feed, last, window, fn means ->
      if means == %{} do
        nil
      else
        v = Enum.map(nodes, &Map.get(means, &1, -100.0))

        nearest_k =
          fingerprints
          |> Enum.map(fn {xy, fp} ->
            d = Enum.zip_with(v, nodes, fn a, n -> (a - Map.get(fp, n, -100.0)) ** 2 end)
            {Enum.sum(d), xy}
          end)
          |> Enum.sort()
          |> Enum.take(k)
          |> Enum.map(&elem(&1, 1))

        x = Enum.sum(Enum.map(nearest_k, &elem(&1, 0))) / length(nearest_k)
        y = Enum.sum(Enum.map(nearest_k, &elem(&1, 1))) / length(nearest_k)
        nearest(building, {x, y})
      end
    end)
  end

  @doc """
  Exact and adjacent rates, zone changes made and true zone changes over `seconds`.

      iex> b = TartarusLats.Building.custom(positions: %{a: {0, 0, 0}, b: {5, 0, 0}, c: {10, 0, 0}}, adjacency: %{a: [:b], b: [:c]}, entrances: [:a])
      iex> truth = %{1 => :a, 2 => :a, 3 => :b, 4 => :b}
      iex> TartarusLats.Replay.Judge.rates(b, %{1 => :a, 2 => :b, 3 => :c, 4 => nil}, truth, 1..4)
      %{seconds: 4, exact: 0.25, adjacent: 0.75, changes: 2, true_changes: 1}
  """
  @spec rates(Building.t(), decisions(), decisions(), Range.t()) :: map()
  def rates(building, decisions, truth, seconds) do
    judged = Enum.filter(seconds, &Map.has_key?(truth, &1))
    n = length(judged)

    exact = Enum.count(judged, &(decisions[&1] != nil and decisions[&1] == truth[&1]))

    adjacent =
      Enum.count(judged, fn s ->
        d = decisions[s]
        d != nil and (d == truth[s] or d in Building.neighbours(building, truth[s]))
      end)

    %{
      seconds: n,
      exact: if(n > 0, do: exact / n),
      adjacent: if(n > 0, do: adjacent / n),
      changes: changes(Enum.map(judged, &decisions[&1])),
      true_changes: changes(Enum.map(judged, &truth[&1]))
    }
  end

  defp changes(seq),
    do: seq |> Enum.reject(&is_nil/1) |> merge() |> length() |> Kernel.-(1) |> max(0)

  @doc """
  A sequence with consecutive repeats merged.

      iex> TartarusLats.Replay.Judge.merge([:a, :a, :b, :a, :a])
      [:a, :b, :a]
  """
  @spec merge(list()) :: list()
  def merge(seq), do: Enum.dedup(seq)

  @doc """
  The Levenshtein distance between two sequences.

      iex> TartarusLats.Replay.Judge.edit_distance([:a, :b, :c], [:a, :c, :d])
      2
  """
  @spec edit_distance(list(), list()) :: non_neg_integer()
  def edit_distance(a, b) do
    b = List.to_tuple(b)
    m = tuple_size(b)
    row0 = Enum.to_list(0..m)

    a
    |> Enum.with_index(1)
    |> Enum.reduce(row0, fn {x, i}, prev ->
      prev_t = List.to_tuple(prev)

      {row, _} =
        Enum.reduce(1..m//1, {[i], i}, fn j, {acc, left} ->
          cost = if x == elem(b, j - 1), do: 0, else: 1

          v = Enum.min([elem(prev_t, j) + 1, left + 1, elem(prev_t, j - 1) + cost])

          {[v | acc], v}
        end)

      Enum.reverse(row)
    end)
    |> List.last()
  end

  @doc """
  The truth's stays, as `TartarusLats.Judge` takes them (`[%{zone:, entered_at:,
  left_at:}]`, the last one open).
  """
  @spec stays(decisions()) :: [map()]
  def stays(truth) do
    truth
    |> Enum.sort()
    |> Enum.chunk_by(&elem(&1, 1))
    |> Enum.map(fn [{s, z} | _] -> %{zone: z, entered_at: s, left_at: nil} end)
    |> close()
  end

  defp close([]), do: []
  defp close([a]), do: [a]
  defp close([a, b | rest]), do: [%{a | left_at: b.entered_at} | close([b | rest])]

  @doc "The zones of the truth (or of decisions) from second 1 to `t`, repeats merged, nils left out."
  @spec zones_until(decisions(), pos_integer()) :: [atom()]
  def zones_until(decisions, t),
    do: 1..t//1 |> Enum.map(&decisions[&1]) |> Enum.reject(&is_nil/1) |> merge()
end
