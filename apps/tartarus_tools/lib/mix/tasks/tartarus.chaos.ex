defmodule Mix.Tasks.Tartarus.Chaos do
  @shortdoc "Migrates agents among real nodes while killing and partitioning them"
  @moduledoc """
  Runs the fault-injection harness (`TartarusTools.Chaos`) and reports whether any agent was
  duplicated or lost.

      mix tartarus.chaos --nodes 8 --agents 500 --migrations 10000 --kills 20 \\
                         --partitions 20 [--persist] [--durable] --seed 1 \\
                         [--census-ms 1000] [--replays 200] [--json] [--out FILE]

  Agents count the messages they take; the workers move them, let them move themselves,
  clone them and post them numbered messages; a census during the run asks every copy to
  answer; at the end every acknowledged message must be in its agent's state (see
  `TartarusTools.Chaos`). `--census-ms 0` turns the census off. A rogue node (no host)
  replays `--replays` captured sealed `prepare` messages to the hosts that received them,
  spread over the run (`0` for none).

  `--durable` starts every host with `durable: true` (acknowledged messages journaled
  before the sender gets `:ok`); a platform without that host option is refused with an
  error before any node starts.

  With `--json` the last line printed is one JSON object with the keys `nodes,
  agents_start, agents_end, clones, clone_failures, untracked_agents, duplicates, lost,
  lost_on_dead_hosts, migrations_done, agent_moves, posts, post_failures, acknowledged,
  acknowledged_missing, acknowledged_missing_after_kill, acknowledged_of_lost_agents,
  census_rounds, transient_duplicates, census_unanswered, replays, kills, partitions,
  persist, host_opts, seed, still_in_doubt, wall_ms`.
  """
  use TartarusTools.CLI

  @switches [
    nodes: :integer,
    agents: :integer,
    migrations: :integer,
    kills: :integer,
    partitions: :integer,
    persist: :boolean,
    durable: :boolean,
    census_ms: :integer,
    replays: :integer,
    seed: :integer,
    json: :boolean,
    out: :string
  ]

  @impl true
  def run(argv) do
    opts = TartarusTools.CLI.parse!(argv, @switches, "tartarus.chaos")
    TartarusTools.CLI.positive!(opts, [:nodes, :agents, :migrations], "tartarus.chaos")
    TartarusTools.CLI.non_negative!(opts, [:kills, :partitions, :census_ms, :replays], "tartarus.chaos")

    Mix.Task.run("app.start")
    host_opts = durable_opts(opts[:durable])
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
        census_ms: opts[:census_ms] || 1_000,
        replays: opts[:replays] || 200,
        host_opts: host_opts,
        progress: progress
      )

    TartarusTools.CLI.report(result, json: opts[:json], out_file: opts[:out])
  end

  # `--durable` is passed to every host as `durable: true`, if the platform has that option.
  defp durable_opts(true) do
    # Asked of the platform itself: a host started with the option, then stopped.
    probe = :"tartarus_chaos_durable_probe_#{System.unique_integer([:positive])}"

    case Tartarus.start_host(probe, durable: true) do
      {:ok, host} ->
        Tartarus.stop_host(host)
        [durable: true]

      {:error, reason} ->
        message = if is_binary(reason), do: reason, else: inspect(reason)

        Mix.raise(
          "mix tartarus.chaos: --durable needs a platform whose hosts take the option " <>
            "`durable: true`; this one does not (#{message})"
        )
    end
  end

  defp durable_opts(_), do: []
end
