defmodule Mix.Tasks.Tartarus.Chaos do
  @shortdoc "Migrates agents among real nodes while killing and partitioning them"
  @moduledoc """
  Runs the fault-injection harness (`TartarusTools.Chaos`) and reports whether any agent was
  duplicated or lost.

      mix tartarus.chaos --nodes 8 --agents 500 --migrations 10000 --kills 20 \\
                         --partitions 20 [--persist] --seed 1 [--json] [--out FILE]

  With `--json` the last line printed is one JSON object with the keys `nodes,
  agents_start, agents_end, duplicates, lost, lost_on_dead_hosts, migrations_done, kills,
  partitions, persist, seed, still_in_doubt, wall_ms`.
  """
  use TartarusTools.CLI

  @switches [
    nodes: :integer,
    agents: :integer,
    migrations: :integer,
    kills: :integer,
    partitions: :integer,
    persist: :boolean,
    seed: :integer,
    json: :boolean,
    out: :string
  ]

  @impl true
  def run(argv) do
    opts = TartarusTools.CLI.parse!(argv, @switches, "tartarus.chaos")
    TartarusTools.CLI.positive!(opts, [:nodes, :agents, :migrations], "tartarus.chaos")
    TartarusTools.CLI.non_negative!(opts, [:kills, :partitions], "tartarus.chaos")

    Mix.Task.run("app.start")
    Logger.configure(level: :error)
    :ok = TartarusTools.Peer.ensure_distributed("chaos")
    total = opts[:migrations] || 10_000
    tty? = match?({:ok, _}, :io.columns(:standard_error))

    progress = fn
      :done -> if tty?, do: IO.write(:stderr, "\n")
      n -> if tty?, do: IO.write(:stderr, "\r  migrations attempted: #{min(n, total)}/#{total}")
    end

    result =
      TartarusTools.Chaos.run(
        nodes: opts[:nodes] || 8,
        agents: opts[:agents] || 500,
        migrations: total,
        kills: opts[:kills] || 20,
        partitions: opts[:partitions] || 20,
        persist: opts[:persist] || false,
        seed: opts[:seed] || 1,
        progress: progress
      )

    TartarusTools.CLI.report(result, json: opts[:json], out_file: opts[:out])
  end
end
