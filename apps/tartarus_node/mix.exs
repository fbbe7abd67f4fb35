defmodule TartarusNode.MixProject do
  use Mix.Project

  # The deployable node: what `mix release` boots on a Linux device or server. It reads the
  # node's configuration file (config/runtime.exs, `TartarusNode.Config`) and starts one
  # Tartarus host with its plugins, persistence, trust list and, when the release carries
  # one, the dashboard (`TartarusNode.Boot`).
  def project do
    [
      app: :tartarus_node,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      start_permanent: Mix.env() == :prod,
      # The platform alone: the dashboard (its own app) and LATS's device side are
      # found at run time when the release carries them (Tartarus.Provides).
      deps: [{:tartarus, in_umbrella: true}]
    ]
  end

  def application do
    # runtime_tools: :observer, :dbg and recon attach to a running node.
    [extra_applications: [:logger, :runtime_tools], mod: {TartarusNode.Application, []}]
  end
end
