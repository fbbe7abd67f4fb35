defmodule Mix.Tasks.Tartarus.Demo do
  @shortdoc "Runs the demo: the platform and every scenario, briefly"

  @schema [
    seed: [type: :pos_integer, default: 1, doc: "seed of every random choice"],
    out: [type: :string, default: "results/demo", doc: "directory of the scenarios' reports"],
    only: [type: :string, doc: "run only the sections whose title starts with this"]
  ]

  @moduledoc """
  The README's first command: a short tour of the platform and of each application.

      mix tartarus.demo [--seed N] [--out DIR] [--only TITLE_PREFIX]

  It starts real BEAM nodes on this machine, so `epmd` must be available (it comes with
  Erlang/OTP). Sections come from `TartarusTools.Demo.sections/0`; scenario sections write their
  reports under `--out`.

  Options (flags are the keys with dashes):

  #{Tartarus.Options.docs(@schema)}
  """
  use TartarusTools.CLI

  @impl true
  def run(argv) do
    opts = TartarusTools.CLI.options!(argv, @schema, "tartarus.demo")
    Mix.Task.run("app.start")
    Logger.configure(level: :warning)

    for section <- TartarusTools.Demo.sections(),
        opts[:only] == nil or String.starts_with?(section.title(), opts[:only]) do
      IO.puts("\n== #{section.title()}")
      t0 = System.monotonic_time(:millisecond)

      case section.run(opts) do
        :ok -> IO.puts("  (#{System.monotonic_time(:millisecond) - t0} ms)")
        {:error, reason} -> Mix.raise("demo section failed: #{inspect(reason)}")
      end
    end
  end
end
