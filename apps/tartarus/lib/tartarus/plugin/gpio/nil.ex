defmodule Tartarus.Plugin.GPIO.Nil do
  @moduledoc """
  The GPIO backend of a node with no GPIO hardware backend, as `Circuits.GPIO`'s nil
  backend is: every call answers `{:error, :no_gpio_backend}`, so a `Tartarus.Plugin.GPIO`
  over it refuses to start (`Tartarus.Plugin.GPIO.check/1` says so before, in one line)
  instead of reading and driving pretend pins.

  It is `Tartarus.Plugin.GPIO`'s default unless the application environment names another
  (`config :tartarus, :gpio_backend, module`) or the plugin's `backend:` option does: the
  firmware's `Circuits.GPIO` backend on a Pi, `Tartarus.Plugin.GPIO.Sim` where pins are
  simulated on purpose (the emulator, tests).

      iex> Tartarus.Plugin.GPIO.Nil.open(17, :output, 0)
      {:error, :no_gpio_backend}
  """
  @behaviour Tartarus.Plugin.GPIO.Backend

  @impl true
  def open(_line, _direction, _initial), do: {:error, :no_gpio_backend}

  @impl true
  def read(_handle), do: {:error, :no_gpio_backend}

  @impl true
  def write(_handle, _level), do: {:error, :no_gpio_backend}

  @impl true
  def watch(_handle, _line), do: {:error, :no_gpio_backend}

  @impl true
  def message(_msg), do: :ignore
end
