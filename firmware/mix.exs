defmodule TartarusFirmware.MixProject do
  # The Nerves firmware of a Tartarus node on a Raspberry Pi (0, 3 or 4): the platform and
  # LATS's device side by path (nothing of the lab: no emulator, benchmarks, chaos, SVG or
  # dashboard; scripts/check-layers checks it), real devices through Circuits.UART and
  # Circuits.GPIO.
  #
  #     export MIX_TARGET=rpi4 TARTARUS_WIFI_SSID=... TARTARUS_WIFI_PSK=...
  #     mix deps.get && mix firmware && mix burn        # or: mix upload tartarus-XXXX.local
  #
  # See docs/devices.md. This project needs hex (nerves, nerves_pack, circuits_*), the
  # nerves_bootstrap archive and Elixir >= 1.17 (rel/vm.args.eex): the umbrella's CI
  # (Elixir 1.14, no hex) never builds it.
  use Mix.Project

  @app :tartarus_firmware
  @version "0.1.0"
  @all_targets [:rpi0, :rpi3, :rpi4]

  def project do
    [
      app: @app,
      version: @version,
      elixir: "~> 1.17",
      archives: [nerves_bootstrap: "~> 1.12"],
      start_permanent: Mix.env() == :prod,
      deps: deps(),
      releases: [{@app, release()}],
      preferred_cli_target: [run: :host, test: :host]
    ]
  end

  def application do
    [
      mod: {TartarusFirmware.Application, []},
      extra_applications: [:logger, :runtime_tools, :crypto, :public_key, :ssl]
    ]
  end

  defp deps do
    [
      # Nerves and the tools of every build
      {:nerves, "~> 1.10", runtime: false},
      {:shoehorn, "~> 0.9.1"},
      {:ring_logger, "~> 0.11.0"},
      {:toolshed, "~> 0.4.0"},

      # The platform and the device code it runs, from this repository
      {:tartarus, path: "../apps/tartarus"},
      {:tartarus_lats_device, path: "../apps/tartarus_lats_device"},

      # Devices
      {:circuits_uart, "~> 1.5"},
      {:circuits_gpio, "~> 2.0"},

      # On the Pis only
      {:nerves_runtime, "~> 0.13.0", targets: @all_targets},
      {:nerves_pack, "~> 0.7.1", targets: @all_targets},
      {:nerves_system_rpi0, "~> 1.24", runtime: false, targets: :rpi0},
      {:nerves_system_rpi3, "~> 1.24", runtime: false, targets: :rpi3},
      {:nerves_system_rpi4, "~> 1.24", runtime: false, targets: :rpi4}
    ]
  end

  def release do
    [
      overwrite: true,
      # Erlang distribution runs over TLS with certificates (see rel/vm.args.eex); the
      # cookie is not what protects it.
      cookie: "#{@app}_cookie",
      include_erts: &Nerves.Release.erts/0,
      steps: [&Nerves.Release.init/1, :assemble],
      strip_beams: Mix.env() == :prod or [keep: ["Docs"]]
    ]
  end
end
