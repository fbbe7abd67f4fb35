defmodule Mix.Tasks.TartarusTools.Demo do
  @shortdoc "Runs the demo: the platform and every scenario, briefly"
  @moduledoc """
  The README's first command: a short tour of the platform and of each application.

      mix tartarus.demo [--seed N] [--out DIR] [--only TITLE_PREFIX]

  It starts real BEAM nodes on this machine, so `epmd` must be available (it comes with
  Erlang/OTP). Sections come from `TartarusTools.Demo.sections/0`; scenario sections write their
  reports under `--out` (default `results/demo`).
  """
  use Mix.Task

  @impl true
  def run(argv) do
    {opts, _, invalid} =
      OptionParser.parse(argv, strict: [seed: :integer, out: :string, only: :string])

    if invalid != [], do: Mix.raise("mix tartarus.demo: invalid options #{inspect(invalid)}")
    Mix.Task.run("app.start")
    Logger.configure(level: :warning)
    opts = Keyword.merge([seed: 1, out: "results/demo"], opts)

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
