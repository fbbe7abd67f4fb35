defmodule TartarusLats.RSSIFilter do
  @moduledoc """
  Moving-average filter for raw RSSI samples.

  The thesis (§3.4.1) found that averaging the last 6 samples (one per
  second) smooths BLE noise well enough while still reacting in a few
  seconds; a larger window is steadier but slower. The window is
  configurable.

  The filter is a plain value: `push/2` returns the new average and the new
  filter. Until the window is full, the average is over the samples seen so
  far. A filter may also start full (`fill:`), which `TartarusLats.Tracker`
  uses to start every tag as "not heard" so that a lone first reading cannot
  look like a strong signal.

      iex> f = TartarusLats.RSSIFilter.new(window: 3)
      iex> {avg, f} = TartarusLats.RSSIFilter.push(f, -60)
      iex> avg
      -60.0
      iex> {_, f} = TartarusLats.RSSIFilter.push(f, -66)
      iex> {avg, f} = TartarusLats.RSSIFilter.push(f, -63)
      iex> avg
      -63.0
      iex> {avg, _f} = TartarusLats.RSSIFilter.push(f, -72)
      iex> avg
      -67.0
  """

  @default_window 6

  defstruct window: @default_window, samples: :queue.new(), count: 0, sum: 0

  @type t :: %__MODULE__{
          window: pos_integer(),
          samples: :queue.queue(number()),
          count: non_neg_integer(),
          sum: number()
        }

  @doc """
  A new, empty filter.

  Options:

    * `:window` - number of samples averaged (positive integer, default #{@default_window});
    * `:fill` - start with the window full of this value (default: empty).

  Raises `ArgumentError` on bad options.

      iex> TartarusLats.RSSIFilter.new() |> TartarusLats.RSSIFilter.average()
      nil
      iex> TartarusLats.RSSIFilter.new(window: 4, fill: -100) |> TartarusLats.RSSIFilter.average()
      -100.0
      iex> TartarusLats.RSSIFilter.new(window: 0)
      ** (ArgumentError) invalid options given to TartarusLats.RSSIFilter.new/1 for key :window: expected a positive integer, got: 0
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    schema = [
      window: [type: :pos_integer, default: @default_window, doc: "samples averaged"],
      fill: [type: :number, doc: "start with the window full of this value"]
    ]

    opts = TartarusLats.Options.validate!(opts, schema, "TartarusLats.RSSIFilter.new/1")
    window = opts[:window]

    case Keyword.fetch(opts, :fill) do
      :error ->
        %__MODULE__{window: window}

      {:ok, value} ->
        samples = Enum.reduce(1..window, :queue.new(), fn _, q -> :queue.in(value, q) end)
        %__MODULE__{window: window, samples: samples, count: window, sum: value * window}
    end
  end

  @doc """
  Adds a sample; returns the average over the last `window` samples and the new filter.

      iex> {avg, _} = TartarusLats.RSSIFilter.new() |> TartarusLats.RSSIFilter.push(-70)
      iex> avg
      -70.0
  """
  @spec push(t(), number()) :: {float(), t()}
  def push(%__MODULE__{} = f, rssi) when is_number(rssi) do
    f =
      if f.count == f.window do
        {{:value, oldest}, rest} = :queue.out(f.samples)
        %{f | samples: :queue.in(rssi, rest), sum: f.sum - oldest + rssi}
      else
        %{f | samples: :queue.in(rssi, f.samples), sum: f.sum + rssi, count: f.count + 1}
      end

    {f.sum / f.count, f}
  end

  @doc """
  The current average, or `nil` when no sample has been pushed.

      iex> TartarusLats.RSSIFilter.new() |> TartarusLats.RSSIFilter.average()
      nil
  """
  @spec average(t()) :: float() | nil
  def average(%__MODULE__{count: 0}), do: nil
  def average(%__MODULE__{sum: sum, count: count}), do: sum / count

  @doc """
  The samples currently in the window, oldest first.

      iex> f = TartarusLats.RSSIFilter.new(window: 2)
      iex> {_, f} = TartarusLats.RSSIFilter.push(f, -1)
      iex> {_, f} = TartarusLats.RSSIFilter.push(f, -2)
      iex> {_, f} = TartarusLats.RSSIFilter.push(f, -3)
      iex> TartarusLats.RSSIFilter.samples(f)
      [-2, -3]
  """
  @spec samples(t()) :: [number()]
  def samples(%__MODULE__{samples: q}), do: :queue.to_list(q)
end
