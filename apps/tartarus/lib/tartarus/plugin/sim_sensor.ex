defmodule Tartarus.Plugin.SimSensor do
  @moduledoc """
  A simulated sensor with a scripted signal, for tests and hosts without hardware.

  Options:

    * `:signal` - a non-empty list of readings, returned one per `read/2` in order and then
      from the start again (required);
    * `:interval_ms` - if set, the sensor also emits each next reading as an event to its
      subscribers every `interval_ms`;
    * `:unit` - a label reported by `describe/1` (default `"unit"`).

  Reads take `nil` or `:value` (the next reading) or `:peek` (the next reading without
  advancing). Writes take `{:script, readings}` (replace the signal) or `:reset`. Anything
  else is `{:error, {:bad_argument, arg}}`.
  """
  @behaviour Tartarus.Plugin

  @impl true
  def init(opts) do
    case Keyword.get(opts, :signal) do
      [_ | _] = signal ->
        interval = Keyword.get(opts, :interval_ms)

        tick =
          if is_integer(interval) and interval > 0,
            do: tick(%{interval: interval, at: Tartarus.Clock.monotonic_time(:millisecond)})

        {:ok,
         %{
           signal: List.to_tuple(signal),
           i: 0,
           unit: Keyword.get(opts, :unit, "unit"),
           tick: tick
         }}

      other ->
        {:error,
         {:bad_option, :signal, "expected a non-empty list of readings, got: #{inspect(other)}"}}
    end
  end

  @impl true
  def describe(s) do
    %{
      kind: :sensor,
      unit: s.unit,
      reads: [:value, :peek],
      writes: [:script, :reset],
      events: [:reading]
    }
  end

  @impl true
  def read(arg, s) when arg in [nil, :value], do: {:ok, current(s), advance(s)}
  def read(:peek, s), do: {:ok, current(s), s}
  def read(arg, s), do: {:error, {:bad_argument, arg}, s}

  @impl true
  def write({:script, [_ | _] = signal}, s), do: {:ok, %{s | signal: List.to_tuple(signal), i: 0}}
  def write(:reset, s), do: {:ok, %{s | i: 0}}
  def write(arg, s), do: {:error, {:bad_argument, arg}, s}

  @impl true
  def handle_info({:tick, at}, %{tick: %{at: at} = tick} = s),
    do: {:events, [{:reading, current(s)}], advance(%{s | tick: tick(tick)})}

  def handle_info(:tick, s), do: {:events, [{:reading, current(s)}], advance(s)}
  def handle_info(_msg, s), do: {:events, [], s}

  # Every `interval` ms of Tartarus.Clock: each tick arms the next, due one interval after
  # the one before (no drift, as with :timer.send_interval/2); only the tick due is one.
  defp tick(%{interval: interval, at: at}) do
    at = at + interval
    Tartarus.Clock.send_after(self(), {:tick, at}, at, abs: true)
    %{interval: interval, at: at}
  end

  defp current(s), do: elem(s.signal, s.i)
  defp advance(s), do: %{s | i: rem(s.i + 1, tuple_size(s.signal))}
end
