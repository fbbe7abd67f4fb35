defmodule TartarusLatsDevice.MixProject do
  use Mix.Project

  # What a LATS node runs on a device (thesis chapter 3), on the platform alone: the HM-10
  # BLE receiver (TartarusLats.HM10, .Receiver) and the beacon plugin, the database agent
  # with its tracker, regions, RSSI filter, zone and motion vectors, the cloud's record, and
  # the queries (Where am I? Where is X? the trace). Its modules keep LATS's names; the
  # experiments (world, simulation, replay, judge, reports, deployments on the emulator) stay
  # in apps/tartarus_lats, which depends on this app. The release and the firmware depend on
  # this app, never on the lab (scripts/check-layers).
  def project do
    [
      app: :tartarus_lats_device,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      start_permanent: Mix.env() == :prod,
      deps: [{:tartarus, in_umbrella: true}]
    ]
  end

  def application do
    [
      extra_applications: [:logger],
      # The BLE receiver a node's {:ble, device} plugin and `mix tartarus.node --ble` use
      # (Tartarus.Plugin.Shorthand finds it here).
      env: [tartarus_ble_plugin: {TartarusLats.HM10.Receiver, :plugin}]
    ]
  end
end
