defmodule TartarusUmbrella.MixProject do
  use Mix.Project

  def project do
    [
      apps_path: "apps",
      version: "0.1.0",
      start_permanent: Mix.env() == :prod,
      deps: [],
      aliases: aliases(),
      preferred_cli_env: ["test.top": :test],
      releases: [tartarus: release()]
    ]
  end

  # `MIX_ENV=prod mix release`: the deployable node (apps/tartarus_node), configured at boot
  # from a file (config/runtime.exs, rel/env.sh.eex; see docs/devices.md). With
  # TARTARUS_RELEASE_ERTS=false the release carries no ERTS and runs on any machine with a
  # matching Erlang/OTP (e.g. Debian's on a Pi); TARTARUS_RELEASE_LATS=false leaves LATS's
  # device side (the HM-10 BLE receiver, the database agent, the queries) out, and
  # TARTARUS_RELEASE_DASHBOARD=false the web dashboard (apps/tartarus_dashboard, on the
  # platform alone; it serves only when the node's file says `dashboard:`).
  # TARTARUS_RELEASE_TOOLS=true adds the tooling app (benchmarks, chaos, SVG: the lab) for
  # the namespace bed alone, whose test (d) runs the chaos harness's agent on release nodes;
  # scripts/check-layers keeps the lab out of the default build.
  defp release do
    [
      applications: release_apps(),
      include_erts: System.get_env("TARTARUS_RELEASE_ERTS") != "false",
      include_executables_for: [:unix]
    ]
  end

  @doc false
  # The applications of the release (scripts/check-layers checks their closure).
  def release_apps do
    lats =
      if System.get_env("TARTARUS_RELEASE_LATS") == "false",
        do: [],
        else: [tartarus_lats_device: :permanent]

    dashboard =
      if System.get_env("TARTARUS_RELEASE_DASHBOARD") == "false",
        do: [],
        else: [tartarus_dashboard: :permanent]

    tools =
      if System.get_env("TARTARUS_RELEASE_TOOLS") == "true",
        do: [tartarus_tools: :permanent],
        else: []

    [tartarus_node: :permanent] ++ lats ++ dashboard ++ tools
  end

  # `mix test` runs every app's unit tests, then the top-level multi-node tests in test/
  # (`mix test.top` runs only those; both take ExUnit's flags, e.g. `--only peer`).
  defp aliases do
    [test: ["test", &top_level_tests/1], "test.top": &top_level_tests/1]
  end

  defp top_level_tests(args) do
    Mix.Task.run("compile", [])

    for app <- [
          :tartarus,
          :tartarus_dashboard,
          :tartarus_tools,
          :tartarus_emu,
          :tartarus_lats,
          :tartarus_warehouse
        ] do
      {:ok, _} = Application.ensure_all_started(app)
    end

    {opts, _, _} =
      OptionParser.parse(args,
        switches: [seed: :integer, only: :keep, include: :keep, exclude: :keep, trace: :boolean]
      )

    Code.require_file("test/test_helper.exs")

    # --exclude adds to what test/test_helper.exs excludes (Tartarus.TestSupport.Tags);
    # --only runs the tag alone, as `mix test --only` does.
    tags = fn key -> for {^key, tag} <- opts, do: String.to_atom(tag) end
    only = tags.(:only)
    excluded = if only == [], do: ExUnit.configuration()[:exclude], else: [:test]

    ExUnit.configure(
      [exclude: excluded ++ tags.(:exclude), include: only ++ tags.(:include)] ++
        Keyword.take(opts, [:seed, :trace])
    )

    # A test file that does not compile fails the run (it would otherwise leave its tests out).
    case Kernel.ParallelCompiler.require(Path.wildcard("test/**/*_test.exs")) do
      {:ok, _, _} -> :ok
      {:error, _, _} -> Mix.raise("top-level tests failed: a test file does not compile")
    end

    %{failures: failures} = ExUnit.run()
    if failures > 0, do: Mix.raise("top-level tests failed")
  end
end
