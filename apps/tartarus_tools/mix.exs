defmodule TartarusTools.MixProject do
  use Mix.Project

  # Experiment tooling beside the platform: benchmarks, the chaos harness, the demo, peer
  # nodes for tests and emulation, CLI helpers, JSON, CSV/summary reports and SVG plots, and
  # the mix tasks that drive them. A node (a Pi's firmware) needs none of it: it depends on
  # the `tartarus` app alone.
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
      deps: [{:tartarus, in_umbrella: true}]
    ]
  end

  def application do
    [
      extra_applications: [:logger, :tools, :inets],
      # tartarus_dashboard: the dashboard a node's `dashboard:` setting starts
      # (Tartarus.Provides; TartarusNode.Boot).
      env: [
        tartarus_demo: [TartarusTools.Demo.Platform],
        tartarus_dashboard: TartarusTools.Dashboard
      ]
    ]
  end
end
