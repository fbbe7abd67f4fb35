# The firmware's configuration, for every target; config/host.exs or config/target.exs
# follows (MIX_TARGET=host, the default, is a laptop build for `mix test` and `iex -S mix`).
import Config

config :tartarus_firmware, target: Mix.target()

# Reproducible builds: the source date of the firmware image.
config :nerves, source_date_epoch: "1732300000"

config :logger, backends: [RingLogger]

if Mix.target() == :host do
  import_config "host.exs"
else
  import_config "target.exs"
end
