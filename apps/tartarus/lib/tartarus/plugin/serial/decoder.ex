defmodule Tartarus.Plugin.Serial.Decoder do
  @moduledoc """
  Turns the bytes of a serial line into events, whatever way the transport chunked them
  (a frame may be split anywhere): the frame format of one kind of device.

  `Tartarus.Plugin.Serial.Lines` (text lines) is the platform's own; an application brings
  the decoders of its devices (LATS brings the HM-10's: its scan output as beacon records).

  A decoder may also answer reads (`read/2`: e.g. the last scan) and describe itself
  (`describe/1`: merged into the plugin's description, so its `:kind` wins).
  """

  @typedoc "A decoder's state."
  @type t :: term()

  @doc "A decoder that has received nothing."
  @callback init(opts :: keyword()) :: {:ok, t()} | {:error, term()}

  @doc "Feeds bytes as they arrived; returns the events completed, in order."
  @callback feed(bytes :: binary(), t()) :: {[term()], t()}

  @doc """
  The device went away: forget a partly received frame (what was completed stays). The
  events returned tell subscribers what was dropped.
  """
  @callback reset(t()) :: {[term()], t()}

  @doc "Answers a read the serial plugin does not answer itself."
  @callback read(args :: term(), t()) :: {:ok, term(), t()} | {:error, term(), t()}

  @doc "Describes the decoded device (merged into the plugin's description)."
  @callback describe(t()) :: map()

  @optional_callbacks read: 2, describe: 1
end
