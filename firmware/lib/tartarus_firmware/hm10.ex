defmodule TartarusFirmware.HM10 do
  @moduledoc """
  An HM-10 BLE receiver on a UART of the Pi, as a `Tartarus.Plugin`: `Tartarus.Plugin.Serial`
  over `Circuits.UART` (`TartarusFirmware.UART`) decoded by `TartarusLats.HM10.Receiver`,
  scanning (`AT+DISI?`) every `:poll_ms`. Reads, writes and events are the serial plugin's
  and the receiver's: `{:scan, t}` is what a LATS database agent reads.

      beacon: {TartarusFirmware.HM10, device: "ttyAMA0", speed: 9600}

  Options: `:device` (required), `:poll_ms` (default 1000), and any other option of
  `Tartarus.Plugin.Serial` (`:speed`, `:backoff_ms`, ...).
  """
  @behaviour Tartarus.Plugin

  alias Tartarus.Plugin.Serial

  @impl true
  def init(opts) do
    {device, opts} = Keyword.pop(opts, :device)
    {_mod, serial_opts} = TartarusLats.HM10.Receiver.plugin(device, opts)
    Serial.init(Keyword.put(serial_opts, :transport, TartarusFirmware.UART))
  end

  @impl true
  defdelegate describe(state), to: Serial

  @impl true
  defdelegate read(args, state), to: Serial

  @impl true
  defdelegate write(args, state), to: Serial

  @impl true
  defdelegate handle_info(msg, state), to: Serial
end
