defmodule TartarusUmbrella.MixProject do
  use Mix.Project

  def project do
    [
      apps_path: "apps",
      version: "0.1.0",
      start_permanent: Mix.env() == :prod,
      deps: [],
      aliases: aliases(),
      preferred_cli_env: ["test.top": :test]
    ]
  end

  # `mix test` runs every app's unit tests, then the top-level multi-node tests in test/.
  defp aliases do
    [test: ["test", "test.top"]]
  end
end
