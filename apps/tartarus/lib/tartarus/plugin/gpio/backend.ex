defmodule Tartarus.Plugin.GPIO.Backend do
  @moduledoc """
  How `Tartarus.Plugin.GPIO` reaches its pins: the calls of `Circuits.GPIO` it needs, so
  the same plugin (and the same read/write contract) runs on simulated pins here
  (`Tartarus.Plugin.GPIO.Sim`) and on a Pi's pins in the firmware (its `Circuits.GPIO`
  backend).

  A handle is whatever `open/3` returns; it is used only by the plugin's process, which
  also receives the backend's edge messages and gives them to `message/1`.
  """

  @typedoc "A pin's line: a number (`17`) or whatever the backend names lines by."
  @type line :: term()

  @doc "Opens `line` as an `:input` or an `:output` (an output starts at `initial`)."
  @callback open(line(), :input | :output, initial :: 0 | 1) :: {:ok, term()} | {:error, term()}

  @doc "The pin's level."
  @callback read(handle :: term()) :: 0 | 1 | {:error, term()}

  @doc "Sets an output's level."
  @callback write(handle :: term(), 0 | 1) :: :ok | {:error, term()}

  @doc "Asks for a message on every edge (both) of an input."
  @callback watch(handle :: term(), line()) :: :ok | {:error, term()}

  @doc "An edge message: `{:edge, line, level}`, or `:ignore` if the message is not one."
  @callback message(msg :: term()) :: {:edge, line(), 0 | 1} | :ignore
end
