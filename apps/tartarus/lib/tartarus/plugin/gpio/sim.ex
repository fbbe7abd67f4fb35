defmodule Tartarus.Plugin.GPIO.Sim do
  @moduledoc """
  Simulated GPIO pins for `Tartarus.Plugin.GPIO`: each pin is a mutable cell (an
  `:atomics`), so a handle behaves like a `Circuits.GPIO` reference. Inputs are driven from
  outside with `stimulate/2` (through the plugin's `{:stimulate, pin, level}` write, so in
  the plugin's process): a watched input that changes level sends an edge message to the
  calling process, as `Circuits.GPIO` sends one to the process that asked for interrupts.

      iex> alias Tartarus.Plugin.GPIO.Sim
      iex> {:ok, led} = Sim.open(17, :output, 0)
      iex> :ok = Sim.write(led, 1)
      iex> Sim.read(led)
      1
      iex> {:ok, button} = Sim.open(27, :input, 0)
      iex> :ok = Sim.watch(button, 27)
      iex> :ok = Sim.stimulate(button, 1)
      iex> receive do msg -> Sim.message(msg) end
      {:edge, 27, 1}
  """
  @behaviour Tartarus.Plugin.GPIO.Backend

  @impl true
  def open(line, direction, initial) when direction in [:input, :output] and initial in [0, 1] do
    # Slot 1: the level; slot 2: 1 once watched.
    cell = :atomics.new(2, [])
    :atomics.put(cell, 1, initial)
    {:ok, %{line: line, direction: direction, cell: cell}}
  end

  def open(_line, direction, initial), do: {:error, {:bad_argument, {direction, initial}}}

  @impl true
  def read(%{cell: cell}), do: :atomics.get(cell, 1)

  @impl true
  def write(%{direction: :output, cell: cell}, level) when level in [0, 1],
    do: :atomics.put(cell, 1, level)

  def write(%{direction: :input}, _level), do: {:error, :not_an_output}
  def write(_handle, level), do: {:error, {:bad_argument, level}}

  @impl true
  def watch(%{direction: :input, cell: cell}, _line), do: :atomics.put(cell, 2, 1)
  def watch(_handle, _line), do: {:error, :not_an_input}

  @impl true
  def message({__MODULE__, :edge, line, level}), do: {:edge, line, level}
  def message(_msg), do: :ignore

  @doc """
  Drives a simulated input to `level` (the outside world: a button, a bump switch). The
  watcher, if any, gets an edge message when the level changes.
  """
  @spec stimulate(term(), 0 | 1) :: :ok | {:error, term()}
  def stimulate(%{direction: :input, cell: cell, line: line}, level) when level in [0, 1] do
    if :atomics.exchange(cell, 1, level) != level and :atomics.get(cell, 2) == 1,
      do: send(self(), {__MODULE__, :edge, line, level})

    :ok
  end

  def stimulate(%{direction: :output}, _level), do: {:error, :not_an_input}
  def stimulate(_handle, level), do: {:error, {:bad_argument, level}}
end
