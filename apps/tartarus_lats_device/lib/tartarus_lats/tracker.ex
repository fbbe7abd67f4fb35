defmodule TartarusLats.Tracker do
  @moduledoc """
  Per-node, per-tag state machine: raw RSSI in, region changes out.

  One tracker runs on each node (it is a plain value; the node's database
  agent keeps it). Feed it once a second, for every tag, either the RSSI the
  receiver reported or `:missing`; it filters, classifies and tells you what
  to store and whom to tell:

      iex> t = TartarusLats.Tracker.new(window: 2, median: 1)
      iex> tag = {"12121212b64445208f0c720eaf059935", 1234, 1111}
      iex> {[], t} = TartarusLats.Tracker.observe(t, 100, tag, -70)
      iex> {[], t} = TartarusLats.Tracker.observe(t, 101, tag, -70)
      iex> {events, t} = TartarusLats.Tracker.observe(t, 102, tag, -70)
      iex> events
      [
        {:record, %{time: 101, uuid: "12121212b64445208f0c720eaf059935", major: 1234, minor: 1111, rssi: -70, region: :far}},
        {:entered_zone, tag, 101}
      ]
      iex> TartarusLats.Tracker.region(t, tag)
      :far

  (A tag the tracker has not heard starts with its filter full of the
  `:missing_rssi` floor, so with a window of 2 the first average is
  (-100 + -70) / 2 = -85, beyond; the second, -70, is far, and the third
  confirms it, dated from the second. `median: 1` turns the spike-rejecting
  median off to keep the example short.)

  ## The exact rule

  For each sample `(time, tag, rssi | :missing)`:

    1. A `:missing` sample counts as the receiver's floor, `:missing_rssi`
       (default -100 dBm). A tag the tracker does not know yet starts with
       its filter full of that floor: it was beyond before.
    2. Spike rejection: the median of the last `:median` samples
       (default 3; 1 turns it off) goes on, so one wild sample never
       reaches the average at all.
    3. That value goes through a `TartarusLats.RSSIFilter` (window
       `:window`, default 6) and the average is classified by
       `TartarusLats.Region.classify/4` into a *candidate* region, with
       hysteresis: it differs from the current region only when the average
       is past a threshold by `:hysteresis_db` (default 1.5 dB), so a tag whose
       average hovers around a threshold does not flip.
    4. Debounce: the candidate replaces the tag's current region only after
       it has been the candidate for `:confirm` consecutive samples
       (default 2, i.e. it held for more than one second at 1 Hz). A
       different candidate in between restarts the count. So a spike that
       crosses beyond -> far and back within a second writes nothing (the
       median removes single-sample spikes; the debounce removes what is
       left of a short excursion of the average).
    5. When a change is confirmed the tracker emits, in this order:
       * `{:record, record}` - the row for the node's durable store, with
         `time` and `rssi` (rounded average, dBm) of the **first** sample of
         the change, so the debounce delays the write but not the timestamp;
       * `{:entered_zone, tag, time}` if the tag was `:beyond`;
       * `{:left_zone, tag, time}` if the tag is now `:beyond` (normally
         from `:far`; a direct near -> beyond change counts too).

       These two say whether this node alone hears the tag. Which zone the
       tag is in is decided with the neighbours by `TartarusLats.Zone`
       (from `heard_average/2` and the region), and that decision, not these
       events, drives the motion-vector handshake
       (`TartarusLats.MotionVectors`) in `TartarusLats.Sim` and
       `TartarusLats.DatabaseAgent`.
    6. A tag that is beyond and whose filter holds only floor samples is
       forgotten (it is indistinguishable from a tag never heard), so the
       tracker's size is bounded by the tags recently heard.

  Nothing else is recorded: a tag staying in one region writes no rows.
  Samples are expected at 1 Hz; the tracker counts samples, it does not
  look at the gaps between timestamps.
  """

  alias TartarusLats.{Beacon, Region, RSSIFilter}

  defstruct calibration: nil,
            correction: {0.0, 1.0},
            window: 6,
            median: 3,
            confirm: 2,
            missing_rssi: -100,
            hysteresis_db: 1.5,
            tags: %{}

  @typedoc "A row for the node's durable store (thesis Figure 3.4)."
  @type record :: %{
          time: number(),
          uuid: Beacon.uuid(),
          major: non_neg_integer(),
          minor: non_neg_integer(),
          rssi: integer(),
          region: Region.t()
        }

  @typedoc "What the caller must do after a sample."
  @type event ::
          {:record, record()}
          | {:entered_zone, Beacon.tag_id(), number()}
          | {:left_zone, Beacon.tag_id(), number()}

  @typedoc false
  @type tag_state :: %{
          filter: RSSIFilter.t(),
          raw: [number()],
          heard: [number() | nil],
          region: Region.t(),
          pending: nil | {Region.t(), number(), pos_integer(), integer()}
        }

  @type t :: %__MODULE__{
          calibration: Region.calibration(),
          correction: {number(), number()},
          window: pos_integer(),
          median: pos_integer(),
          confirm: pos_integer(),
          missing_rssi: number(),
          hysteresis_db: number(),
          tags: %{Beacon.tag_id() => tag_state()}
        }

  @schema [
    calibration: [
      type: :any,
      check: {:struct, Region, "a TartarusLats.Region calibration"},
      doc: "a calibration (default `TartarusLats.Region.calibrate/0`)"
    ],
    correction: [
      type: :any,
      default: {0.0, 1.0},
      doc:
        "this receiver's `{offset, slope}`: every sample becomes `(rssi - offset) / slope` (`TartarusLats.Replay.Calibration`)"
    ],
    window: [type: :pos_integer, default: 6, doc: "moving-average window"],
    median: [
      type: :pos_integer,
      default: 3,
      check: :odd,
      doc: "spike-rejecting median window"
    ],
    confirm: [type: :pos_integer, default: 2, doc: "samples that confirm a change"],
    missing_rssi: [type: :number, default: -100, doc: "dBm of a missing sample"],
    hysteresis_db: [
      type: :number,
      default: 1.5,
      doc: "how far past a threshold the average must be to change region"
    ]
  ]

  @doc """
  A new tracker.

  Options:

    * `:calibration` - a `t:TartarusLats.Region.calibration/0`
      (default `TartarusLats.Region.calibrate/0`: -65 / -73 dBm);
    * `:correction` - this receiver's `{offset, slope}` (default `{0.0, 1.0}`, none):
      every RSSI sample becomes `(rssi - offset) / slope` before anything else, so a
      receiver that reports louder or softer than the common model is put on it
      (`TartarusLats.Replay.Calibration`);
    * `:window` - moving-average window (default 6);
    * `:median` - spike-rejecting median over this many raw samples before
      the average (odd positive integer, default 3; 1 disables it);
    * `:confirm` - consecutive samples that confirm a change (default 2);
    * `:missing_rssi` - value of a `:missing` sample in dBm (default -100);
    * `:hysteresis_db` - how far past a threshold (dB) the average must be for
      the candidate to be another region (default 1.5; 0 turns it off, see
      `TartarusLats.Region.classify/4`).

  Raises `ArgumentError` naming the key on a bad option.

      iex> TartarusLats.Tracker.new(confirm: 0)
      ** (ArgumentError) invalid options given to TartarusLats.Tracker.new/1 for key :confirm: expected a positive integer, got: 0
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    opts = TartarusLats.Options.validate!(opts, @schema, "TartarusLats.Tracker.new/1")
    cal = Keyword.get_lazy(opts, :calibration, fn -> Region.calibrate() end)

    correction =
      case opts[:correction] do
        {o, s} when is_number(o) and is_number(s) and s > 0 ->
          {o, s}

        other ->
          raise ArgumentError,
                "invalid options given to TartarusLats.Tracker.new/1 for key :correction: expected {offset, slope} with slope > 0, got: #{inspect(other)}"
      end

    %__MODULE__{
      calibration: cal,
      correction: correction,
      window: opts[:window],
      median: opts[:median],
      confirm: opts[:confirm],
      missing_rssi: opts[:missing_rssi],
      hysteresis_db: opts[:hysteresis_db]
    }
  end

  @doc """
  Feeds one sample for one tag; returns the events (in order) and the new tracker.

  `rssi` is the receiver's RSSI in dBm or `:missing` when the tag was not
  heard this second.
  """
  @spec observe(t(), number(), Beacon.tag_id(), number() | :missing) :: {[event()], t()}
  def observe(%__MODULE__{} = t, time, {uuid, major, minor} = tag, rssi)
      when is_number(time) and is_binary(uuid) and is_integer(major) and is_integer(minor) and
             (is_number(rssi) or rssi == :missing) do
    state = Map.get_lazy(t.tags, tag, fn -> fresh(t) end)
    rssi = correct(t.correction, rssi)
    value = if rssi == :missing, do: t.missing_rssi, else: rssi
    raw = Enum.take([value | state.raw], t.median)
    heard = Enum.take([if(rssi == :missing, do: nil, else: rssi) | state.heard], t.window)
    {avg, filter} = RSSIFilter.push(state.filter, median(raw))
    candidate = Region.classify(avg, t.calibration, state.region, t.hysteresis_db)
    state = %{state | filter: filter, raw: raw, heard: heard}

    {events, state} =
      cond do
        candidate == state.region ->
          {[], %{state | pending: nil}}

        match?({^candidate, _, _, _}, state.pending) ->
          {^candidate, since, count, first_avg} = state.pending
          maybe_confirm(t, tag, %{state | pending: {candidate, since, count + 1, first_avg}})

        true ->
          maybe_confirm(t, tag, %{state | pending: {candidate, time, 1, round(avg)}})
      end

    {events, %{t | tags: store(t, tag, state)}}
  end

  def observe(%__MODULE__{}, time, tag, rssi) do
    raise ArgumentError,
          "invalid sample given to TartarusLats.Tracker.observe/4: expected a numeric time, " <>
            "a {uuid, major, minor} tag and an RSSI number or :missing, got: " <>
            "#{inspect(time)}, #{inspect(tag)}, #{inspect(rssi)}"
  end

  @doc """
  Feeds one second of readings: `readings` maps tags to RSSI or `:missing`.

  Tags the tracker knows but that are absent from `readings` get a
  `:missing` sample, so a node can pass only what its receiver heard. Tags
  are processed in sorted order, so the event list is deterministic.

      iex> t = TartarusLats.Tracker.new()
      iex> tag = {"00000000000000000000000000000001", 1, 1}
      iex> {_events, t} = Enum.reduce(1..8, {[], t}, fn s, {_, t} ->
      ...>   TartarusLats.Tracker.tick(t, s, %{tag => -60}) end)
      iex> TartarusLats.Tracker.region(t, tag)
      :near
      iex> {events, t} = Enum.reduce(9..20, {[], t}, fn s, {acc, t} ->
      ...>   {ev, t} = TartarusLats.Tracker.tick(t, s, %{}); {acc ++ ev, t} end)
      iex> for {kind, _, _} <- events, kind != :record, do: kind
      [:left_zone]
      iex> TartarusLats.Tracker.tags(t)
      []
  """
  @spec tick(t(), number(), %{Beacon.tag_id() => number() | :missing}) :: {[event()], t()}
  def tick(%__MODULE__{} = t, time, readings) when is_map(readings) do
    tags = (Map.keys(readings) ++ Map.keys(t.tags)) |> Enum.uniq() |> Enum.sort()

    Enum.reduce(tags, {[], t}, fn tag, {acc, t} ->
      {events, t} = observe(t, time, tag, Map.get(readings, tag, :missing))
      {[events | acc], t}
    end)
    |> then(fn {acc, t} -> {acc |> Enum.reverse() |> List.flatten(), t} end)
  end

  @doc """
  The confirmed region of a tag (`:beyond` for a tag the tracker does not know).
  """
  @spec region(t(), Beacon.tag_id()) :: Region.t()
  def region(%__MODULE__{tags: tags}, tag) do
    case tags do
      %{^tag => %{region: region}} -> region
      _ -> :beyond
    end
  end

  @doc """
  The current filtered RSSI of a tag, or `nil` for a tag the tracker does not know.
  """
  @spec average(t(), Beacon.tag_id()) :: float() | nil
  def average(%__MODULE__{tags: tags}, tag) do
    case tags do
      %{^tag => %{filter: f}} -> RSSIFilter.average(f)
      _ -> nil
    end
  end

  @doc """
  The mean of the samples of `tag` actually heard in the last `:window` seconds (missing
  samples left out), or `nil` when none was heard (or the tag is unknown).

  Unlike `average/2`, which counts a lost packet as the floor so that a tag that went away
  fades, this value does not dip when a few packets are lost: it is what neighbouring
  nodes compare to decide which zone a tag is in (`TartarusLats.Zone`).

      iex> t = TartarusLats.Tracker.new(window: 3, median: 1)
      iex> tag = {"00000000000000000000000000000001", 1, 1}
      iex> {_, t} = TartarusLats.Tracker.observe(t, 1, tag, -60)
      iex> {_, t} = TartarusLats.Tracker.observe(t, 2, tag, :missing)
      iex> {_, t} = TartarusLats.Tracker.observe(t, 3, tag, -70)
      iex> {TartarusLats.Tracker.heard_average(t, tag), TartarusLats.Tracker.average(t, tag)}
      {-65.0, -76.66666666666667}
  """
  @spec heard_average(t(), Beacon.tag_id()) :: float() | nil
  def heard_average(%__MODULE__{tags: tags}, tag) do
    case tags do
      %{^tag => %{heard: heard}} ->
        case Enum.reject(heard, &is_nil/1) do
          [] -> nil
          values -> Enum.sum(values) / length(values)
        end

      _ ->
        nil
    end
  end

  @doc """
  How many samples of `tag` were heard in the last `:window` seconds (0 if unknown); with
  `at_least`, only those of at least `at_least` dBm.

      iex> t = TartarusLats.Tracker.new(window: 3, median: 1)
      iex> tag = {"00000000000000000000000000000001", 1, 1}
      iex> {_, t} = TartarusLats.Tracker.observe(t, 1, tag, -60)
      iex> {_, t} = TartarusLats.Tracker.observe(t, 2, tag, :missing)
      iex> {_, t} = TartarusLats.Tracker.observe(t, 3, tag, -80)
      iex> {TartarusLats.Tracker.heard_count(t, tag), TartarusLats.Tracker.heard_count(t, tag, -73)}
      {2, 1}
  """
  @spec heard_count(t(), Beacon.tag_id(), number() | nil) :: non_neg_integer()
  def heard_count(%__MODULE__{tags: tags}, tag, at_least \\ nil) do
    case tags do
      %{^tag => %{heard: heard}} when at_least == nil -> Enum.count(heard, &is_number/1)
      %{^tag => %{heard: heard}} -> Enum.count(heard, &(is_number(&1) and &1 >= at_least))
      _ -> 0
    end
  end

  @doc "The tags the tracker currently keeps state for, sorted."
  @spec tags(t()) :: [Beacon.tag_id()]
  def tags(%__MODULE__{tags: tags}), do: tags |> Map.keys() |> Enum.sort()

  @doc "Tags whose confirmed region is near or far (present in this zone), sorted."
  @spec present(t()) :: [Beacon.tag_id()]
  def present(%__MODULE__{tags: tags}) do
    Enum.sort(for {tag, %{region: r}} <- tags, r != :beyond, do: tag)
  end

  defp correct(_, :missing), do: :missing
  defp correct({o, s}, rssi) when o == 0 and s == 1, do: rssi
  defp correct({o, s}, rssi), do: (rssi - o) / s

  defp fresh(t) do
    %{
      filter: RSSIFilter.new(window: t.window, fill: t.missing_rssi),
      raw: List.duplicate(t.missing_rssi, t.median),
      heard: [],
      region: :beyond,
      pending: nil
    }
  end

  defp maybe_confirm(t, {uuid, major, minor} = tag, %{pending: {new, since, count, avg}} = state)
       when count >= t.confirm do
    old = state.region
    record = %{time: since, uuid: uuid, major: major, minor: minor, rssi: avg, region: new}

    events =
      [{:record, record}] ++
        if(old == :beyond, do: [{:entered_zone, tag, since}], else: []) ++
        if(new == :beyond, do: [{:left_zone, tag, since}], else: [])

    {events, %{state | region: new, pending: nil}}
  end

  defp maybe_confirm(_t, _tag, state), do: {[], state}

  defp store(t, tag, %{region: :beyond, pending: nil, filter: filter} = state) do
    if Enum.all?(RSSIFilter.samples(filter) ++ state.raw, &(&1 == t.missing_rssi)),
      do: Map.delete(t.tags, tag),
      else: Map.put(t.tags, tag, state)
  end

  defp store(t, tag, state), do: Map.put(t.tags, tag, state)

  # The nearest-rank median (as `TartarusTools.Stats.median/1`, which a device does not
  # carry): the lower middle sample of an even count.
  defp median(xs) do
    sorted = Enum.sort(xs)
    Enum.at(sorted, max(0, ceil(length(sorted) / 2) - 1))
  end
end
