defmodule Mix.Tasks.Tartarus.Dashboard.Bench do
  @shortdoc "Measures the web dashboard: migration throughput with and without a page, 10,000 hosts"
  @moduledoc """
  Runs `TartarusEmu.DashboardBench` and writes its figures as JSON.

      mix tartarus.dashboard.bench [--rounds 5] [--moves 200] [--agents 16] [--hosts 8]
                                   [--no-big] [--big-rows 100 --big-cols 100 --big-agents 1000]
                                   [--out results/dashboard-bench.json]

  Options (flags are the keys with dashes):

  #{Tartarus.Options.docs(TartarusEmu.DashboardBench.schema())}

  `--out FILE` (default `results/dashboard-bench.json`) is where the JSON goes; the last
  line printed is the same JSON. The page is a real headless Chromium when `chromium` is
  installed (see `docs/dashboard.md`).
  """
  use TartarusTools.CLI

  @impl true
  def run(argv) do
    {out, argv} = take_out(argv, "results/dashboard-bench.json", [])

    opts =
      TartarusTools.CLI.options!(
        argv,
        TartarusEmu.DashboardBench.schema(),
        "tartarus.dashboard.bench"
      )

    Mix.Task.run("app.start")

    case TartarusEmu.DashboardBench.run(opts) do
      {:ok, result} ->
        json = TartarusTools.JSON.encode!(result, pretty: true)
        File.mkdir_p!(Path.dirname(out))
        File.write!(out, json <> "\n")
        Mix.shell().info("written to #{out}")
        IO.puts(TartarusTools.JSON.encode!(result))

      {:error, reason} ->
        Mix.raise("mix tartarus.dashboard.bench: #{reason}")
    end
  end

  defp take_out(["--out", path | rest], _default, acc), do: take_out(rest, path, acc)
  defp take_out([x | rest], default, acc), do: take_out(rest, default, [x | acc])
  defp take_out([], default, acc), do: {default, Enum.reverse(acc)}
end
