defmodule TartarusImmune.MixProject do
  use Mix.Project

  def project do
    [
      app: :tartarus_immune,
      version: "0.1.0",
      build_path: "../../_build",
      config_path: "../../config/config.exs",
      deps_path: "../../deps",
      lockfile: "../../mix.lock",
      elixir: "~> 1.14",
      start_permanent: Mix.env() == :prod,
      deps: [
        {:tartarus, in_umbrella: true},
        {:tartarus_dashboard, in_umbrella: true},
        {:tartarus_tools, in_umbrella: true},
        {:tartarus_emu, in_umbrella: true},
        {:tartarus_arena, in_umbrella: true}
      ]
    ]
  end

  def application do
    [
      extra_applications: [:logger],
      env: [tartarus_demo: [TartarusImmune.Demo, TartarusImmune.Evolution.Demo]]
    ]
  end
end
