defmodule TartarusLats.Region do
  @moduledoc """
  The three regions of a zone and the calibration that separates them.

  The thesis (§3.3.3) describes a tag's position relative to one Pi-node by
  three regions instead of the noisy RSSI itself:

    * `:near` - closer than 2 m (strong signal);
    * `:far` - between 2 m and 5 m (weak signal);
    * `:beyond` - not detected, or farther than 5 m.

  A `calibration` holds the two thresholds in dBm: an average RSSI at or above
  `near_dbm` is near, at or above `far_dbm` is far, anything lower (or no
  signal at all) is beyond. Thresholds come either from the log-distance
  path-loss model (`calibrate/1`, the same model `TartarusLats.Radio`
  simulates) or are given explicitly (`calibration/2`, e.g. measured on site
  as in the thesis).

      iex> cal = TartarusLats.Region.calibrate(tx_power: -59, exponent: 2.0)
      iex> {Float.round(cal.near_dbm, 1), Float.round(cal.far_dbm, 1)}
      {-65.0, -73.0}
      iex> TartarusLats.Region.classify(-62.5, cal)
      :near
      iex> TartarusLats.Region.classify(-70.0, cal)
      :far
      iex> TartarusLats.Region.classify(:none, cal)
      :beyond
  """

  @enforce_keys [:near_dbm, :far_dbm]
  defstruct [:near_dbm, :far_dbm]

  @typedoc "A region of a zone, nearest first."
  @type t :: :near | :far | :beyond

  @typedoc "Thresholds in dBm, `near_dbm > far_dbm`."
  @type calibration :: %__MODULE__{near_dbm: number(), far_dbm: number()}

  @doc """
  Thresholds from the log-distance model: the mean RSSI at `near_m` and `far_m`.

  `rssi(d) = tx_power - 10 * exponent * log10(d)`.

  Options (all optional): `:tx_power` (dBm at 1 m, default -59), `:exponent`
  (path-loss exponent, default 2.0), `:near_m` (default 2.0), `:far_m`
  (default 5.0). Raises `ArgumentError` on bad values.

      iex> TartarusLats.Region.calibrate(near_m: 6.0, far_m: 5.0)
      ** (ArgumentError) invalid options given to TartarusLats.Region.calibrate/1: expected 0 < near_m < far_m, got: near_m: 6.0, far_m: 5.0
  """
  @spec calibrate(keyword()) :: calibration()
  def calibrate(opts \\ []) do
    schema = [
      tx_power: [type: :number, default: -59, doc: "dBm at 1 m"],
      exponent: [
        type: :number,
        default: 2.0,
        check: :positive,
        doc: "path-loss exponent"
      ],
      near_m: [type: :number, default: 2.0, doc: "near distance (m)"],
      far_m: [type: :number, default: 5.0, doc: "far distance (m)"]
    ]

    opts = TartarusLats.Options.validate!(opts, schema, "TartarusLats.Region.calibrate/1")
    [tx, n, near_m, far_m] = Enum.map([:tx_power, :exponent, :near_m, :far_m], &opts[&1])

    unless near_m > 0 and near_m < far_m do
      raise ArgumentError,
            "invalid options given to TartarusLats.Region.calibrate/1: expected 0 < near_m < far_m, " <>
              "got: near_m: #{inspect(near_m)}, far_m: #{inspect(far_m)}"
    end

    %__MODULE__{
      near_dbm: tx - 10 * n * :math.log10(near_m),
      far_dbm: tx - 10 * n * :math.log10(far_m)
    }
  end

  @doc """
  Explicit thresholds (dBm). Raises `ArgumentError` unless `near_dbm > far_dbm`.

      iex> TartarusLats.Region.calibration(-60, -75)
      %TartarusLats.Region{near_dbm: -60, far_dbm: -75}
  """
  @spec calibration(number(), number()) :: calibration()
  def calibration(near_dbm, far_dbm)
      when is_number(near_dbm) and is_number(far_dbm) and near_dbm > far_dbm,
      do: %__MODULE__{near_dbm: near_dbm, far_dbm: far_dbm}

  def calibration(near_dbm, far_dbm) do
    raise ArgumentError,
          "invalid thresholds given to TartarusLats.Region.calibration/2: expected numbers with " <>
            "near_dbm > far_dbm, got: #{inspect(near_dbm)}, #{inspect(far_dbm)}"
  end

  @doc """
  The region for a (filtered) RSSI; `:none` or `nil` (no signal) is beyond.

      iex> cal = TartarusLats.Region.calibration(-65, -73)
      iex> Enum.map([-64, -65, -66, -73, -74, nil], &TartarusLats.Region.classify(&1, cal))
      [:near, :near, :far, :far, :beyond, :beyond]
  """
  @spec classify(number() | :none | nil, calibration()) :: t()
  def classify(rssi, %__MODULE__{near_dbm: near, far_dbm: far}) do
    cond do
      not is_number(rssi) -> :beyond
      rssi >= near -> :near
      rssi >= far -> :far
      true -> :beyond
    end
  end

  @doc """
  The region for a (filtered) RSSI, given the region the tag is in now, with hysteresis: a
  tag leaves its region only when the RSSI is past a threshold by `hysteresis_db` (toward
  a weaker region: below the threshold by that much; toward a stronger one: above it by
  that much). With 0 it is `classify/2`. So a tag that stands still where its average
  hovers around a threshold stays in one region.

      iex> cal = TartarusLats.Region.calibration(-65, -73)
      iex> TartarusLats.Region.classify(-74, cal, :far, 3)
      :far
      iex> TartarusLats.Region.classify(-76.5, cal, :far, 3)
      :beyond
      iex> TartarusLats.Region.classify(-71, cal, :beyond, 3)
      :beyond
      iex> TartarusLats.Region.classify(-69, cal, :beyond, 3)
      :far
      iex> TartarusLats.Region.classify(-60, cal, :beyond, 3)
      :near
  """
  @spec classify(number() | :none | nil, calibration(), t(), number()) :: t()
  def classify(rssi, cal, current, hysteresis_db) when is_number(rssi) and hysteresis_db >= 0 do
    plain = classify(rssi, cal)

    cond do
      rank(plain) < rank(current) ->
        weaker = classify(rssi + hysteresis_db, cal)
        if rank(weaker) < rank(current), do: weaker, else: current

      rank(plain) > rank(current) ->
        stronger = classify(rssi - hysteresis_db, cal)
        if rank(stronger) > rank(current), do: stronger, else: current

      true ->
        current
    end
  end

  def classify(_no_signal, _cal, _current, _hysteresis_db), do: :beyond

  defp rank(:near), do: 2
  defp rank(:far), do: 1
  defp rank(:beyond), do: 0
end
