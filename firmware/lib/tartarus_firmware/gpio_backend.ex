defmodule TartarusFirmware.GPIOBackend do
  @moduledoc """
  A `Tartarus.Plugin.GPIO.Backend` over `Circuits.GPIO` (2.x; 1.x has the same calls): the
  Pi's pins behind the contract of `Tartarus.Plugin.GPIO`. Edges come from
  `Circuits.GPIO.set_interrupts/2` as `{:circuits_gpio, line, timestamp, level}`.
  """
  @behaviour Tartarus.Plugin.GPIO.Backend

  @impl true
  def open(line, :output, initial), do: Circuits.GPIO.open(line, :output, initial_value: initial)
  def open(line, :input, _initial), do: Circuits.GPIO.open(line, :input)

  @impl true
  def read(gpio), do: Circuits.GPIO.read(gpio)

  @impl true
  def write(gpio, level), do: Circuits.GPIO.write(gpio, level)

  @impl true
  def watch(gpio, _line), do: Circuits.GPIO.set_interrupts(gpio, :both)

  @impl true
  def message({:circuits_gpio, line, _timestamp, level}) when level in [0, 1],
    do: {:edge, line, level}

  def message(_msg), do: :ignore
end
