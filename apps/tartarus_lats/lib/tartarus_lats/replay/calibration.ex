defmodule TartarusLats.Replay.Calibration do
  @moduledoc """
  Per-receiver RSSI calibration, learnt once from standing-still reference recordings, as
  a deployment would do it.

  ## The reference recordings

  A directory of files `<receiver name>_<x>_<y>_<z>.<ext>` (the tetam `fingerprints/`
  sets): the beacon standing still at `(x, y, z)` (metres), the readings of one receiver,
  in the log format of `TartarusLats.Replay.Log` (four columns suffice). `points/2` reads
  them into one mean RSSI per receiver and point.

  ## The model and the corrections

  All the points of all receivers fit one log-distance model by least squares,
  `rssi = tx_power - 10 * exponent * log10(d)` (`d` the 3-D distance, at least 0.5 m).
  Receivers differ (Raspberry Pi radios and USB dongles, at two heights), so each gets a
  correction that maps what it reports onto that common model:

    * `:offset` (the default): `corrected = raw - offset`, `offset` the receiver's mean
      residual against the model;
    * `:slope`: `corrected = (raw - a) / b`, `a, b` from the least-squares line of the
      receiver's means against the model's values (offset and path-loss slope).

  `fit/3` returns the model, each receiver's correction `{offset, slope}` (slope 1.0 for
  `:offset`) and the RMS residual before and after. The correction is stored per node and
  applied by the node's tracker to every sample (`TartarusLats.Tracker`, option
  `:correction`), so the tracker and the zone decision (`TartarusLats.Zone`) see corrected
  RSSI and the thresholds of the common model (`thresholds/2`).

  `write!/2` and `read!/1` keep a calibration as JSON:

      {"model": {"tx_power": -60.1, "exponent": 1.9}, "kind": "offset",
       "receivers": {"sensor10": {"offset": 3.2, "slope": 1.0, "points": 82, ...}, ...}}
  """

  alias TartarusLats.Replay.{Devices, Log}

  @typedoc "A calibration: the common model and a correction per node (receiver name)."
  @type t :: %{
          model: %{tx_power: float(), exponent: float()},
          kind: :offset | :slope,
          receivers: %{atom() => %{offset: float(), slope: float()}}
        }

  @doc """
  Reads the reference recordings of `dir` for the receivers of `devices`: `[%{node:,
  pos: {x, y, z}, distance:, mean:, n:}]`, one per receiver and point that has readings.
  Files whose name does not match, or of receivers not in `devices`, are skipped; so are
  malformed lines (`TartarusLats.Replay.Log`).
  """
  @spec points(Path.t(), Devices.t()) :: [map()]
  def points(dir, devices) do
    by_name = Map.new(devices, fn {_id, d} -> {Atom.to_string(d.name), d} end)

    dir
    |> File.ls!()
    |> Enum.sort()
    |> Enum.flat_map(fn file ->
      with [name, x, y, z] <- file |> Path.rootname() |> String.split("_"),
           %{} = dev <- by_name[name],
           {x, ""} <- Float.parse(x),
           {y, ""} <- Float.parse(y),
           {z, ""} <- Float.parse(z),
           %{readings: [_ | _] = rs} <- Log.read!(Path.join(dir, file)) do
        values = Enum.map(rs, & &1.rssi)

        [
          %{
            node: dev.name,
            pos: {x, y, z},
            distance: distance(dev.pos, {x, y, z}),
            mean: Enum.sum(values) / length(values),
            n: length(values)
          }
        ]
      else
        _ -> []
      end
    end)
  end

  defp distance({a, b, c}, {x, y, z}),
    do: max(:math.sqrt((a - x) ** 2 + (b - y) ** 2 + (c - z) ** 2), 0.5)

  @doc """
  Fits the model and the per-receiver corrections to `points` (`points/2`). `kind` is
  `:offset` or `:slope` (see the moduledoc).

      iex> pts = for {node, off} <- [a: 3.0, b: -2.0], d <- [1.0, 2.0, 4.0, 8.0],
      ...>   do: %{node: node, distance: d, mean: -60 - 20 * :math.log10(d) + off}
      iex> cal = TartarusLats.Replay.Calibration.fit(pts, :offset)
      iex> {Float.round(cal.model.exponent, 3), Float.round(cal.receivers.a.offset, 3), Float.round(cal.receivers.b.offset, 3)}
      {2.0, 2.5, -2.5}
  """
  @spec fit([map()], :offset | :slope) :: t()
  def fit(points, kind) when kind in [:offset, :slope] and points != [] do
    {a, b} = line(Enum.map(points, &{:math.log10(&1.distance), &1.mean}))
    model = fn d -> a + b * :math.log10(d) end

    receivers =
      points
      |> Enum.group_by(& &1.node)
      |> Map.new(fn {node, pts} ->
        expected = Enum.map(pts, &model.(&1.distance))
        means = Enum.map(pts, & &1.mean)

        {offset, slope} =
          case kind do
            :offset ->
              {Enum.sum(Enum.zip_with(means, expected, &(&1 - &2))) / length(pts), 1.0}

            :slope ->
              {oa, ob} = line(Enum.zip(expected, means))

              if ob > 0.2,
                do: {oa, ob},
                else: {Enum.sum(means) / length(pts) - mean(expected), 1.0}
          end

        corrected = Enum.map(means, &((&1 - offset) / slope))

        {node,
         %{
           offset: offset,
           slope: slope,
           points: length(pts),
           rms_raw_db: rms(means, expected),
           rms_corrected_db: rms(corrected, expected)
         }}
      end)

    %{model: %{tx_power: a, exponent: -b / 10}, kind: kind, receivers: receivers}
  end

  defp mean(xs), do: Enum.sum(xs) / length(xs)

  defp rms(xs, ys),
    do: :math.sqrt(Enum.sum(Enum.zip_with(xs, ys, &((&1 - &2) ** 2))) / length(xs))

  # Least-squares line y = a + b x through {x, y} pairs.
  defp line(pairs) do
    n = length(pairs)
    mx = Enum.sum(Enum.map(pairs, &elem(&1, 0))) / n
    my = Enum.sum(Enum.map(pairs, &elem(&1, 1))) / n
    sxx = Enum.sum(Enum.map(pairs, fn {x, _} -> (x - mx) ** 2 end))
    sxy = Enum.sum(Enum.map(pairs, fn {x, y} -> (x - mx) * (y - my) end))
    b = if sxx == 0, do: 0.0, else: sxy / sxx
    {my - b * mx, b}
  end

  @doc "The correction of a node, `{offset, slope}` (`{0.0, 1.0}` when it has none)."
  @spec correction(t() | nil, atom()) :: {float(), float()}
  def correction(nil, _node), do: {0.0, 1.0}

  def correction(cal, node) do
    case cal.receivers do
      %{^node => %{offset: o, slope: s}} -> {o * 1.0, s * 1.0}
      _ -> {0.0, 1.0}
    end
  end

  @doc """
  The near/far thresholds (`TartarusLats.Region`) of the common model at `near_m` and
  `far_m` metres; without a calibration, the radio model's defaults (`TartarusLats.Region.calibrate/1`).
  """
  @spec thresholds(t() | nil, keyword()) :: TartarusLats.Region.calibration()
  def thresholds(nil, opts), do: TartarusLats.Region.calibrate(opts)

  def thresholds(cal, opts) do
    TartarusLats.Region.calibrate(
      [tx_power: cal.model.tx_power, exponent: cal.model.exponent] ++ opts
    )
  end

  @doc "Writes a calibration as JSON."
  @spec write!(Path.t(), t()) :: :ok
  def write!(path, cal) do
    json = %{
      model: cal.model,
      kind: cal.kind,
      receivers: Map.new(cal.receivers, fn {n, r} -> {Atom.to_string(n), r} end)
    }

    File.write!(path, Tartarus.JSON.encode!(json) <> "\n")
  end

  @doc "Reads a calibration written by `write!/2`. Raises `ArgumentError` on a malformed file."
  @spec read!(Path.t()) :: t()
  def read!(path) do
    with {:ok, %{"model" => %{"tx_power" => a, "exponent" => n}, "receivers" => rs} = j}
         when is_number(a) and is_number(n) and is_map(rs) <-
           Tartarus.JSON.decode(File.read!(path)) do
      %{
        model: %{tx_power: a * 1.0, exponent: n * 1.0},
        kind: if(j["kind"] == "slope", do: :slope, else: :offset),
        receivers:
          Map.new(rs, fn {name, r} ->
            {String.to_atom(name), %{offset: r["offset"] * 1.0, slope: (r["slope"] || 1.0) * 1.0}}
          end)
      }
    else
      other ->
        raise ArgumentError, "calibration #{path}: not a calibration file: #{inspect(other)}"
    end
  end
end
