import Config

config :logger, :console, format: "$time [$level] $metadata$message\n", metadata: [:host]

# `mix tartarus.node --ble PATH` attaches the BLE receiver this function makes (the tooling
# names no application; the umbrella chooses LATS's HM-10 receiver).
config :tartarus_tools, :ble_plugin, {TartarusLats.HM10.Receiver, :plugin}

import_config "#{config_env()}.exs"
