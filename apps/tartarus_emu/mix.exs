defmodule TartarusEmu.MixProject do
  use Mix.Project

  def project do
    [
      app: :tartarus_emu,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      elixirc_paths: elixirc_paths(Mix.env()),
      start_permanent: Mix.env() == :prod,
      deps: [
        {:tartarus, in_umbrella: true},
        {:tartarus_dashboard, in_umbrella: true},
        {:tartarus_tools, in_umbrella: true}
      ]
    ]
  end

  def application do
    [
      extra_applications: [:logger],
      mod: {TartarusEmu.Application, []},
      env: [tartarus_demo: [TartarusEmu.Demo]]
    ]
  end

  defp elixirc_paths(:test), do: ["lib", "test/support"]
  defp elixirc_paths(_), do: ["lib"]
end
