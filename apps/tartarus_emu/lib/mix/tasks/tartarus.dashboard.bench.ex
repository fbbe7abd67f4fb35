defmodule Mix.Tasks.Tartarus.Dashboard.Bench do
  @shortdoc "Measures the web dashboard: migration throughput with and without a page, 10,000 hosts"
  @moduledoc """
  Runs `TartarusEmu.DashboardBench` and writes its figures as JSON.

      mix tartarus.dashboard.bench [--rounds 5] [--moves 200] [--agents 16] [--hosts 8]
                                   [--no-big] [--big-rows 100 --big-cols 100 --big-agents 1000]
                                   [--out results/dashboard-bench.json] [--json]

  Options (flags are the keys with dashes):

  #{TartarusTools.CLI.flag_docs(TartarusEmu.DashboardBench.schema())}

  `--out FILE` (default `results/dashboard-bench.json`) is where the JSON goes; the last
  line printed is the same JSON. The page is a real headless Chromium when `chromium` is
  installed (see `docs/dashboard.md`).
  """
  use TartarusTools.CLI, out: :file

  @impl true
  def run(argv) do
    schema =
      TartarusEmu.DashboardBench.schema() ++
        [
          out: [
            type: :string,
            default: "results/dashboard-bench.json",
            doc: "where the JSON goes"
          ],
          json: [
            type: :boolean,
            default: false,
            doc: "print only the JSON (the last line is the JSON in any case)"
          ]
        ]

    opts = TartarusTools.CLI.options!(argv, schema, "tartarus.dashboard.bench")
    {out, json?} = {opts[:out], opts[:json]}
    opts = opts |> Keyword.drop([:out, :json]) |> Keyword.update(:quiet, json?, &(&1 or json?))

    Mix.Task.run("app.start")

    case TartarusEmu.DashboardBench.run(opts) do
      {:ok, result} ->
        result = Map.put_new(result, :provenance, TartarusTools.Provenance.collect())
        json = Tartarus.JSON.encode!(result, pretty: true)
        File.mkdir_p!(Path.dirname(out))
        File.write!(out, json <> "\n")
        unless json?, do: Mix.shell().info("written to #{out}")
        TartarusTools.CLI.report(result, json: true)

      {:error, reason} ->
        TartarusTools.CLI.error!("tartarus.dashboard.bench", reason)
    end
  end
end
