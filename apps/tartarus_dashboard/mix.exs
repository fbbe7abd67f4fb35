defmodule TartarusDashboard.MixProject do
  use Mix.Project

  # The web dashboard of a node (TartarusDashboard): its HTTP/1.1 server on :gen_tcp, the
  # JSON API, the live feed, the fleet view, the health sampler, the page; on the platform
  # alone, so that a release and a device may carry it without the lab. The lab (the
  # emulator, the tooling, the applications' experiments) depends on this app for its
  # panels and emulations, never the reverse (scripts/check-layers).
  def project do
    [
      app: :tartarus_dashboard,
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
      # :inets only for TartarusDashboard.http_get/2 (scripts and tests that read the API
      # from Elixir): the dashboard itself serves on :gen_tcp.
      extra_applications: [:logger, :crypto, inets: :optional],
      # tartarus_dashboard: the dashboard a node's `dashboard:` setting starts
      # (Tartarus.Provides; TartarusNode.Boot).
      env: [tartarus_dashboard: TartarusDashboard]
    ]
  end
end
