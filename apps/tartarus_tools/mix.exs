defmodule TartarusTools.MixProject do
  use Mix.Project

  # Experiment tooling beside the platform: benchmarks, the chaos harness, the demo, peer
  # nodes for tests and emulation, CLI helpers, a headless browser for the dashboard's page
  # tests, CSV/summary reports and SVG plots, and the mix tasks that drive them (the
  # dashboard itself is apps/tartarus_dashboard, which `mix tartarus.node --dashboard`
  # starts). A node (a Pi's firmware, the release) needs none of it.
  def project do
    [
      app: :tartarus_tools,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      start_permanent: Mix.env() == :prod,
      deps: [{:tartarus, in_umbrella: true}, {:tartarus_dashboard, in_umbrella: true}]
    ]
  end

  def application do
    [
      extra_applications: [:logger, :tools, :inets],
      env: [tartarus_demo: [TartarusTools.Demo.Platform]]
    ]
  end
end
