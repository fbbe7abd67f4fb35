defmodule TartarusFirmware do
  @moduledoc """
  The firmware of a Tartarus node on a Raspberry Pi (Nerves): at boot it starts Erlang
  distribution over TLS (`TartarusFirmware.Distribution`) and one Tartarus host named after
  the Pi, with the Pi's devices as plugins:

    * `TartarusFirmware.HM10` - an HM-10 BLE receiver on a UART, through `Circuits.UART`
      (`TartarusFirmware.UART`, a `Tartarus.Plugin.Serial.Transport`), decoded by LATS's
      `TartarusLats.HM10.Receiver`: a LATS node's `:beacon`;
    * `TartarusFirmware.GPIO` - named pins through `Circuits.GPIO`
      (`TartarusFirmware.GPIOBackend`, a `Tartarus.Plugin.GPIO.Backend`), the contract of
      the simulated `Tartarus.Plugin.GPIO`.

  Configuration (`config/target.exs`): `:plugins` (`[{name, {module, opts}}]`), `:data`
  (default `/data/tartarus`: `certs/`, `trusted/`, `host/`), `:node_basename` (default
  `"tartarus"`), `:distribution` (start distribution at boot).
  """

  @doc "The name of this Pi's Tartarus host: its host name, as an atom (`:\"tartarus-1a2b\"`)."
  @spec host() :: atom()
  def host do
    {:ok, name} = :inet.gethostname()
    List.to_atom(name)
  end

  @doc "The firmware's data directory (certificates, trusted issuers, durable agents)."
  @spec data_dir() :: Path.t()
  def data_dir, do: Application.get_env(:tartarus_firmware, :data, "/data/tartarus")
end
