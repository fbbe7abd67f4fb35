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
  use Mix.Task

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
    {opts, args, invalid} = OptionParser.parse(argv, strict: @switches)

    if invalid != [],
      do:
        Mix.raise(
          "mix tartarus.bench: invalid options #{inspect(invalid)}; see `mix help tartarus.bench`"
        )

    Mix.Task.run("app.start")

    result =
      case args do
        ["migration"] ->
          mode =
            case opts[:mode] || "virtual" do
              "virtual" ->
                :virtual

              "peer" ->
                :peer

              other ->
                Mix.raise("mix tartarus.bench: --mode must be virtual or peer, got: #{other}")
            end

          positive!(opts, [:hops, :agents, :state_bytes])
          unless opts[:json], do: Mix.shell().info("migration benchmark (#{mode})...")

          Tartarus.Bench.migration(
            mode: mode,
            hops: opts[:hops] || 1_000,
            agents: opts[:agents] || 1,
            state_bytes: opts[:state_bytes] || 1024,
            tls: opts[:tls] || false
          )

        ["agents"] ->
          positive!(opts, [:count, :creators])
          unless opts[:json], do: Mix.shell().info("resident agents benchmark...")

          Tartarus.Bench.agents(
            count: opts[:count] || 100_000,
            creators: opts[:creators] || System.schedulers_online()
          )

        _ ->
          Mix.raise(
            "usage: mix tartarus.bench migration|agents [options]; see `mix help tartarus.bench`"
          )
      end

    json = Tartarus.JSON.encode!(result)
    if opts[:out], do: File.write!(opts[:out], json <> "\n")

    if opts[:json] do
      Mix.shell().info(json)
    else
      Enum.each(Enum.sort(result), fn {k, v} -> Mix.shell().info("  #{k}: #{inspect(v)}") end)
    end
  end

  defp positive!(opts, keys) do
    for k <- keys, v = opts[k], v != nil, v <= 0 do
      Mix.raise(
        "mix tartarus.bench: --#{String.replace(to_string(k), "_", "-")} must be a positive integer, got: #{v}"
      )
    end
  end
end
