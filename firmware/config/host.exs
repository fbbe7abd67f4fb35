# A laptop build of the firmware: no distribution started by the firmware (use `iex --sname`),
# simulated pins (asked for: the default GPIO backend has none), no UART.
import Config

config :tartarus_firmware,
  distribution: false,
  plugins: [
    io:
      {Tartarus.Plugin.GPIO,
       pins: [led: {17, :output}, button: {27, :input}], backend: Tartarus.Plugin.GPIO.Sim}
  ]
