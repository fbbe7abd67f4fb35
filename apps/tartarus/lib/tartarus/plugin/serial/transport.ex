defmodule Tartarus.Plugin.Serial.Transport do
  @moduledoc """
  How `Tartarus.Plugin.Serial` reaches a serial device: open it, write to it, close it, and
  turn the messages the device's process receives into data, "opened" and "closed".

  Two transports exist: `Tartarus.Plugin.Serial.Tty` (any Linux tty, configured with `stty`
  and read through an Erlang port; no dependency) in the platform, and the firmware's
  `Circuits.UART` transport on a Pi. A transport's state is owned by the serial plugin's
  process; the messages it causes arrive there and are given to `message/2`.
  """

  @typedoc "A transport's connection state."
  @type t :: term()

  @typedoc "What a message meant: bytes read, the device is open, or it went away."
  @type item :: :opened | {:data, binary()} | {:closed, reason :: term()}

  @doc """
  Starts opening `device` (a path such as `/dev/ttyUSB0`) with `opts` (`:speed` in baud and
  the transport's own options). `{:ok, t}` means the attempt is under way: the device counts
  as open once `message/2` returns `:opened`.
  """
  @callback open(device :: String.t(), opts :: keyword()) :: {:ok, t()} | {:error, term()}

  @doc "Writes bytes to the device."
  @callback write(t(), iodata()) :: :ok | {:error, term()}

  @doc "Closes the device (no message about it follows)."
  @callback close(t()) :: :ok

  @doc """
  Interprets a message received by the plugin's process: `{items, t}` if it came from this
  connection, `:ignore` otherwise.
  """
  @callback message(msg :: term(), t()) :: {[item()], t()} | :ignore
end
