defmodule TartarusFirmware.GPIO do
  @moduledoc """
  The Pi's GPIO pins as a `Tartarus.Plugin`: `Tartarus.Plugin.GPIO` over `Circuits.GPIO`
  (`TartarusFirmware.GPIOBackend`), so agents read and write the same names and levels as
  on simulated pins, and get the same `{:edge, name, level}` events.

      io: {TartarusFirmware.GPIO, pins: [led: {17, :output}, button: {27, :input}]}
  """
  @behaviour Tartarus.Plugin

  alias Tartarus.Plugin.GPIO

  @impl true
  def init(opts), do: GPIO.init(Keyword.put(opts, :backend, TartarusFirmware.GPIOBackend))

  @impl true
  defdelegate describe(state), to: GPIO

  @impl true
  defdelegate read(args, state), to: GPIO

  @impl true
  defdelegate write(args, state), to: GPIO

  @impl true
  defdelegate handle_info(msg, state), to: GPIO
end
