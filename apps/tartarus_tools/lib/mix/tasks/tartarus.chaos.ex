defmodule Mix.Tasks.Tartarus.Chaos do
  @shortdoc "Migrates agents among real nodes while killing and partitioning them"
  @moduledoc """
  Runs the fault-injection harness (`TartarusTools.Chaos`) and reports whether any agent was
  duplicated or lost.

      mix tartarus.chaos --nodes 8 --agents 500 --migrations 10000 --kills 20 \\
                         --partitions 20 [--server-kills 0] [--persist] [--durable] \\
                         --seed 1 \\
                         [--census-ms 1000] [--replays 200] [--json] [--out FILE]

  Agents count the messages they take; the workers move them, let them move themselves,
  clone them and post them numbered messages; a census during the run asks every copy to
  answer; at the end every acknowledged message must be in its agent's state (see
  `TartarusTools.Chaos`). `--census-ms 0` turns the census off. A rogue node (no host)
  replays `--replays` captured sealed `prepare` messages to the hosts that received them,
  spread over the run (`0` for none).

  `--server-kills N` adds N kills (`Process.exit(pid, :kill)`) of a node's host server to
  the faults: the node and its agents stay up while the host's supervisor starts a new
  server, which adopts them; an agent lost to it counts as lost.

  `--durable` starts every host with `durable: true` (acknowledged messages journaled
  before the sender gets `:ok`); a platform without that host option is refused with an
  error before any node starts.

  With `--json` the last line printed is one JSON object with the keys `nodes,
  agents_start, agents_end, clones, clone_failures, untracked_agents, duplicates, lost,
  lost_on_dead_hosts, migrations_done, agent_moves, posts, post_failures, acknowledged,
  acknowledged_missing, acknowledged_missing_after_kill, acknowledged_of_lost_agents,
  census_rounds, transient_duplicates, census_unanswered, replays, kills, partitions,
  server_kills,
  persist, host_opts, seed, still_in_doubt, wall_ms`, the verdict line as `verdict` and
  `ok` (true when it says OK), and `provenance` (`TartarusTools.Provenance`). Without
  `--json` the keys are printed one a line, then the verdict line (`verdict/1`):

      3 lost (3 on killed nodes), 0 duplicated, 0 transient duplicates, 0 acknowledged messages missing: OK
  """
  use TartarusTools.CLI, out: :file

  @switches [
    nodes: :integer,
    agents: :integer,
    migrations: :integer,
    kills: :integer,
    partitions: :integer,
    server_kills: :integer,
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
    TartarusTools.CLI.non_negative!(opts, [:kills, :partitions, :server_kills, :census_ms, :replays], "tartarus.chaos")

    if opts[:nodes] && opts[:nodes] < 2,
      do: Mix.raise("mix tartarus.chaos: --nodes must be at least 2, got: #{opts[:nodes]}")

    Mix.Task.run("app.start")
    host_opts = durable_opts(opts[:durable])
    Logger.configure(level: :error)
    :ok = TartarusTools.Peer.ensure_distributed("chaos")
    total = opts[:migrations] || 10_000
    # "what, k of n, elapsed, ETA" on a terminal; nothing under --json or when redirected.
    shown = TartarusTools.Progress.new(total, label: "chaos: migrations", quiet: opts[:json])

    progress = fn
      :done -> if shown.enabled, do: IO.write(:stderr, "\n")
      n -> TartarusTools.Progress.draw(%{shown | done: min(n, total)})
    end

    result =
      TartarusTools.Chaos.run(
        nodes: opts[:nodes] || 8,
        agents: opts[:agents] || 500,
        migrations: total,
        kills: opts[:kills] || 20,
        partitions: opts[:partitions] || 20,
        server_kills: opts[:server_kills] || 0,
        persist: opts[:persist] || false,
        seed: opts[:seed] || 1,
        census_ms: opts[:census_ms] || 1_000,
        replays: opts[:replays] || 200,
        host_opts: host_opts,
        progress: progress
      )

    if opts[:json] || opts[:out] do
      result = Map.merge(result, %{verdict: verdict(result), ok: verdict(result) =~ ": OK"})
      TartarusTools.CLI.report(result, json: opts[:json], out_file: opts[:out])
    end

    unless opts[:json] do
      if opts[:out] == nil, do: TartarusTools.CLI.report(result, [])
      Mix.shell().info(verdict(result))
    end
  end

  @doc """
  The verdict line of a chaos run: agents lost, duplicated and seen twice by the census,
  then `OK`, or `FAILED` with what broke a guarantee: any duplicate (lasting or transient);
  a lost agent that was not on a killed node (without `--persist`; with it, any lost agent);
  an acknowledged message missing from a live agent (without `--durable`, those of agents
  restored from their arrival snapshot after a kill are reported apart, not as a failure).

      iex> Mix.Tasks.Tartarus.Chaos.verdict(%{lost: 0, lost_on_dead_hosts: 0, duplicates: 0, transient_duplicates: 0, acknowledged_missing: 0, acknowledged_missing_after_kill: 0, persist: true, host_opts: "[]"})
      "0 lost, 0 duplicated, 0 transient duplicates, 0 acknowledged messages missing: OK"
      iex> Mix.Tasks.Tartarus.Chaos.verdict(%{lost: 3, lost_on_dead_hosts: 3, duplicates: 0, transient_duplicates: 0, acknowledged_missing: 2, acknowledged_missing_after_kill: 2, persist: false, host_opts: "[]"})
      "3 lost (3 on killed nodes), 0 duplicated, 0 transient duplicates, 2 acknowledged messages missing (2 after a kill): OK"
      iex> Mix.Tasks.Tartarus.Chaos.verdict(%{lost: 2, lost_on_dead_hosts: 0, duplicates: 1, transient_duplicates: 0, acknowledged_missing: 0, acknowledged_missing_after_kill: 0, persist: true, host_opts: "[]"})
      "2 lost, 1 duplicated, 0 transient duplicates, 0 acknowledged messages missing: FAILED (2 agents lost, 1 duplicated)"
  """
  @spec verdict(map()) :: String.t()
  def verdict(r) do
    get = &Map.get(r, &1, 0)
    {lost, on_dead, missing, after_kill} =
      {get.(:lost), get.(:lost_on_dead_hosts), get.(:acknowledged_missing),
       get.(:acknowledged_missing_after_kill)}

    # `host_opts` is the inspected keyword list of the hosts' options.
    durable? = to_string(Map.get(r, :host_opts, "")) =~ "durable: true"
    bad_lost = if Map.get(r, :persist, false), do: lost, else: lost - on_dead
    bad_missing = if durable?, do: missing, else: missing - after_kill

    failures =
      for {n, what} <- [
            {bad_lost, "agents lost"},
            {get.(:duplicates), "duplicated"},
            {get.(:transient_duplicates), "transient duplicates"},
            {bad_missing, "acknowledged messages missing"}
          ],
          n > 0,
          do: "#{n} #{what}"

    lost_text = if on_dead > 0, do: "#{lost} lost (#{on_dead} on killed nodes)", else: "#{lost} lost"

    missing_text =
      if after_kill > 0,
        do: "#{missing} acknowledged messages missing (#{after_kill} after a kill)",
        else: "#{missing} acknowledged messages missing"

    "#{lost_text}, #{get.(:duplicates)} duplicated, #{get.(:transient_duplicates)} transient duplicates, " <>
      "#{missing_text}: " <>
      if(failures == [], do: "OK", else: "FAILED (#{Enum.join(failures, ", ")})")
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
