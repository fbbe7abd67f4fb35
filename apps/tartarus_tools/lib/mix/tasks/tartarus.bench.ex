defmodule Mix.Tasks.Tartarus.Bench do
  @shortdoc "Benchmarks migration (against the BEAM floor), churn, busy agents, creation"
  @moduledoc """
  Benchmarks the platform's real paths.

      mix tartarus.bench migration [--mode virtual|peer] [--latency-hops N] [--agents K]
                                   [--hops H] [--rounds R] [--state-bytes B] [--tls]
                                   [--profile eprof]
                                   [--json] [--out FILE]
      mix tartarus.bench agents [--count N] [--creators C] [--profile eprof] [--json]
                                [--out FILE]
      mix tartarus.bench churn [--migrations N] [--agents K] [--hops H] [--no-persist]
                               [--json] [--out FILE]
      mix tartarus.bench busy [--messages N] [--senders S] [--dwell-ms D] [--cast]
                              [--max-seconds T] [--json] [--out FILE]
      mix tartarus.bench durability [--agents K] [--hops H] [--messages N] [--senders S]
                                    [--json] [--out FILE]

  `migration` runs, in one run between the same two hosts, the platform and the floor
  (three distribution messages and a spawn of a paused process carrying the same state, no
  platform; see `TartarusTools.Bench.Floor`): one agent making N hops (default 2000:
  latency) and K agents (default 1000) making H hops each (default 100: throughput), each
  split in R rounds (default 4) alternating floor and platform so load changes of a shared
  machine weigh on both alike. Both
  hosts are in this VM (`--mode virtual`, default) or each on its own BEAM node (`--mode
  peer`, two `:peer` nodes on loopback; `--tls` runs their distribution over TLS with
  mutual certificate authentication). `--profile eprof` profiles the platform's
  throughput phase on the receiving node (in one round) and prints its costliest
  functions. Keys: `mode, tls, latency_hops, hops, rounds, agents, state_bytes, total_hops, latency_wall_ms, wall_ms,
  us_per_hop, floor_us_per_hop, ratio_latency, median_us, p99_us, samples, hops_per_s,
  floor_hops_per_s, ratio_throughput, module_bytes_shipped, distribution, otp_release,
  schedulers` (and `profile`).

  `agents` creates N idle agents (default 100000) on one host of a fresh peer node. Keys:
  `agents, resident, creators, wall_ms, spawn_per_s, bytes_per_agent, memory_mb,
  process_limit` (and `profile`).

  `churn` makes N migrations (default 1,000,000) between two hosts of this VM with default
  options (batches of K fresh agents, default 1000, each making H hops, default 10, then
  ending) and reports the memory of the hosts' tables after 10,000, 100,000 and 1,000,000
  migrations (and N), each once the batches' agents have ended and their ends were handled
  (`settle_ms_at`: how long that took): key `memory_bytes_at`, an object keyed by count; then again with
  persistence (`data_dir:`), adding the journal's size (`persist.journal_bytes_at`);
  `--no-persist` skips that pass. `moves_failed` (and `persist.moves_failed`) counts moves
  that failed and were tried again (an agent gives up after 10 in a row, and the run stops
  saying why). See `TartarusTools.Bench.Churn`.

  `busy` has S senders (default 4) post N messages in all (default 50,000) to one agent
  hopping continuously between two peer nodes, and reports messages delivered exactly
  once, duplicates, acknowledged but missing, failure reasons with counts and per-sender
  order. With `--cast` the senders cast instead (`Tartarus.cast/3`, 2 ms apart; keys
  `cast_failed_reports`, `cast_unknown_reports`, `reported_failed_yet_delivered`: a
  failure report must mean "not delivered"; casts keep no order between them).
  The agent moves on at once at every arrival, or after D ms (`--dwell-ms`);
  senders stop after T seconds (default 120; the rest counts as not sent). See
  `TartarusTools.Bench.Busy`.

  `durability` measures the cost of durability: hops and posts per second between two
  hosts of this VM without a data directory, with one (`data_dir:`), and with `durable:
  true` as well (K agents, default 200, making H hops each, default 50; S senders, default
  4, posting N messages in all, default 20,000, to one agent). Keys: `configs` (by
  configuration: `hops_per_s, posts_per_s, us_per_post, journal_bytes`),
  `durable_posts_ratio`, `durable_hops_ratio`, `journal_posts_ratio`, `journal_hops_ratio`
  (each / the configuration without a data directory). See
  `TartarusTools.Bench.Durability`.

  With `--json` the last line printed is one JSON object; `--out FILE` also writes it to a
  file.
  """
  use TartarusTools.CLI, out: :file

  @switches [
    mode: :string,
    latency_hops: :integer,
    rounds: :integer,
    hops: :integer,
    agents: :integer,
    state_bytes: :integer,
    tls: :boolean,
    count: :integer,
    creators: :integer,
    profile: :string,
    migrations: :integer,
    persist: :boolean,
    messages: :integer,
    senders: :integer,
    dwell_ms: :integer,
    cast: :boolean,
    max_seconds: :integer,
    json: :boolean,
    out: :string
  ]

  @task "tartarus.bench"

  @impl true
  def run(argv) do
    {opts, args} = TartarusTools.CLI.parse!(argv, @switches, @task, args: true)

    TartarusTools.CLI.positive!(
      opts,
      [
        :latency_hops,
        :rounds,
        :hops,
        :agents,
        :state_bytes,
        :count,
        :creators,
        :migrations,
        :messages,
        :senders,
        :max_seconds
      ],
      @task
    )

    TartarusTools.CLI.non_negative!(opts, [:dwell_ms], @task)
    profile = TartarusTools.CLI.choice!(opts[:profile], [:eprof], :profile, @task, nil)
    Mix.Task.run("app.start")
    say = fn text -> unless opts[:json], do: Mix.shell().info(text) end

    result =
      case args do
        ["migration"] ->
          mode = TartarusTools.CLI.choice!(opts[:mode], [:virtual, :peer], :mode, @task, :virtual)
          say.("migration benchmark (#{mode}), platform and floor...")

          TartarusTools.Bench.migration(
            mode: mode,
            latency_hops: opts[:latency_hops] || 2_000,
            hops: opts[:hops] || 100,
            agents: opts[:agents] || 1_000,
            rounds: opts[:rounds] || 4,
            state_bytes: opts[:state_bytes] || 1024,
            tls: opts[:tls] || false,
            profile: profile
          )

        ["agents"] ->
          say.("resident agents benchmark...")

          TartarusTools.Bench.agents(
            count: opts[:count] || 100_000,
            creators: opts[:creators] || System.schedulers_online(),
            profile: profile
          )

        ["churn"] ->
          say.("churn benchmark...")

          TartarusTools.Bench.Churn.run(
            migrations: opts[:migrations] || 1_000_000,
            agents: opts[:agents] || 1_000,
            hops: opts[:hops] || 10,
            persist: Keyword.get(opts, :persist, true),
            progress: fn n -> say.("  #{n} migrations") end
          )

        ["busy"] ->
          say.("busy agent benchmark...")

          TartarusTools.Bench.Busy.run(
            messages: opts[:messages] || 50_000,
            senders: opts[:senders] || 4,
            dwell_ms: opts[:dwell_ms] || 0,
            max_seconds: opts[:max_seconds] || 120,
            via: if(opts[:cast], do: :cast, else: :post)
          )

        ["durability"] ->
          say.("durability cost benchmark...")

          TartarusTools.Bench.Durability.run(
            agents: opts[:agents] || 200,
            hops: opts[:hops] || 50,
            messages: opts[:messages] || 20_000,
            senders: opts[:senders] || 4
          )

        _ ->
          given = if args == [], do: "none", else: Enum.join(args, " ")

          Mix.raise(
            "mix tartarus.bench: expected one benchmark, migration, agents, churn, busy or " <>
              "durability, got: #{given}; see `mix help tartarus.bench`"
          )
      end

    TartarusTools.CLI.report(result, [json: opts[:json], out_file: opts[:out]], &text/1)
  end

  defp text(result) do
    {top, result} = Map.pop(result, :profile)

    lines =
      Enum.map(Enum.sort(result), fn {k, v} -> "  #{k}: #{inspect(v, limit: :infinity)}" end)

    Enum.join(lines ++ if(top, do: profile_lines(top), else: []), "\n")
  end

  defp profile_lines(%{total_us: total, top: lines}),
    do: ["eprof, costliest functions (total #{total} us profiled):" | Enum.map(lines, &("  " <> &1))]
end
