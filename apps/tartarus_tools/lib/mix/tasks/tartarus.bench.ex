defmodule Mix.Tasks.Tartarus.Bench do
  @shortdoc "Benchmarks migration and resident agents"
  @moduledoc """
  Benchmarks the platform's real paths.

      mix tartarus.bench migration [--mode virtual|peer] [--hops N] [--agents K]
                                   [--state-bytes B] [--tls] [--json] [--out FILE]
      mix tartarus.bench agents [--count N] [--creators C] [--json] [--out FILE]

  `migration` bounces `K` agents (default 1) `N` times (default 1000) between two hosts:
  both in this VM (`--mode virtual`, default) or each on its own BEAM node (`--mode peer`,
  two `:peer` nodes on loopback; `--tls` runs their distribution over TLS with mutual
  certificate authentication). Keys: `mode, tls, hops, agents, state_bytes, total_hops,
  wall_ms, median_us, p99_us, samples, hops_per_s, module_bytes_shipped, distribution`.

  `agents` creates `N` idle agents (default 100000) on one host of a fresh peer node.
  Keys: `agents, resident, creators, wall_ms, spawn_per_s, bytes_per_agent, memory_mb`.

  With `--json` the last line printed is one JSON object; `--out FILE` also writes it to a
  file.
  """
  use TartarusTools.CLI

  @switches [
    mode: :string,
    hops: :integer,
    agents: :integer,
    state_bytes: :integer,
    tls: :boolean,
    count: :integer,
    creators: :integer,
    json: :boolean,
    out: :string
  ]

  @impl true
  def run(argv) do
    {opts, args} = TartarusTools.CLI.parse!(argv, @switches, "tartarus.bench", args: true)

    TartarusTools.CLI.positive!(
      opts,
      [:hops, :agents, :state_bytes, :count, :creators],
      "tartarus.bench"
    )

    Mix.Task.run("app.start")

    result =
      case args do
        ["migration"] ->
          mode =
            TartarusTools.CLI.choice!(
              opts[:mode],
              [:virtual, :peer],
              :mode,
              "tartarus.bench",
              :virtual
            )

          unless opts[:json], do: Mix.shell().info("migration benchmark (#{mode})...")

          TartarusTools.Bench.migration(
            mode: mode,
            hops: opts[:hops] || 1_000,
            agents: opts[:agents] || 1,
            state_bytes: opts[:state_bytes] || 1024,
            tls: opts[:tls] || false
          )

        ["agents"] ->
          unless opts[:json], do: Mix.shell().info("resident agents benchmark...")

          TartarusTools.Bench.agents(
            count: opts[:count] || 100_000,
            creators: opts[:creators] || System.schedulers_online()
          )

        _ ->
          Mix.raise(
            "usage: mix tartarus.bench migration|agents [options]; see `mix help tartarus.bench`"
          )
      end

    TartarusTools.CLI.report(result, json: opts[:json], out_file: opts[:out])
  end
end
