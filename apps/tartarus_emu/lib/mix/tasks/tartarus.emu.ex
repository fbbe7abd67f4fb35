defmodule Mix.Tasks.Tartarus.Emu do
  @shortdoc "Runs the generic emulation: agents walking a topology"
  @moduledoc """
  Runs the generic walk scenario (`TartarusEmu.Walk`): mobile agents random-walking or
  conscientiously exploring a topology whose nodes break off and reconnect.

      mix tartarus.emu [--topology grid|ring|line|random|FILE] [--hosts N] [--agents N]
                       [--steps N] [--mode virtual|peer] [--group K]
                       [--strategy random|conscientious] [--p P] [--latency-ms MS]
                       [--loss P] [--seed N] [--out DIR] [--until-covered]
                       [--keep-events] [--quiet] [--json] [--help]
                       [--dashboard PORT] [--step-ms MS] [--time real|virtual]

  Defaults (those of `TartarusEmu.Walk.schema/0`): a 16-host grid, 4 agents, 100 steps,
  virtual mode, random walk, `p = 0`, seed 1 (as every task), output in
  `results/walk-<timestamp>/`. `--help` prints this text.

  Each step, every agent makes one move (see `TartarusEmu.Walk` for the step model), so a
  run is deterministic for a given `--seed`. `--mode peer` puts each host (or each group of
  `--group K` hosts) in its own BEAM node, connected only to its neighbours' nodes.

  The output directory gets `series.csv` and one CSV and SVG per series (`coverage`,
  `migrations`, `failed_moves`, `down_nodes`, `bytes`), `moves.svg`, and up to 2,000
  hosts `topology.svg` (nodes and links) and `walk.svg` (agent 1's walk hop by hop, with
  `walk_path.csv`; see `TartarusEmu.Figures`), the log's CSVs
  (`log_steps.csv`, `log_hosts.csv`, `log_links.csv`, `log_events.csv` with
  `--keep-events`), `summary.md` and `summary.json`.

  With `--json` the last line printed is one JSON object with the summary keys: `hosts,
  agents, steps, mode, strategy, topology, seed, p, migrations, migrations_per_s,
  failed_moves, messages, bytes, energy_mj, wall_ms, steps_ms, coverage, ...` (see
  `TartarusEmu.Walk`: `wall_ms` is the run's real time, pauses of `--step-ms` included).

  `--dashboard PORT` serves the web dashboard (`TartarusDashboard`, on 127.0.0.1)
  while the walk runs and prints its address and action token; `--step-ms MS` pauses
  after each step so that a person can watch (see `docs/dashboard.md`).

  `--time virtual` runs the walk in virtual time (`Tartarus.Clock.Virtual`, seeded with
  `--seed`): the links' latencies and the agents' waits are the only time, CPU is none, and
  the same seed gives the same numbers however loaded the machine is (`wall_ms` stays the
  machine's). Only with `--mode virtual`: networks of real BEAM nodes run in real time. See
  `docs/emulator.md`, "Time".

  Large virtual runs (more processes or ETS tables than this VM allows, e.g. 10,000 hosts
  and 100,000 agents) run in a fresh BEAM node started with `+P` and `+e` large enough, so
  no `ELIXIR_ERL_OPTIONS` are needed; the summary's `runner` says where the run ran.
  """
  use TartarusTools.CLI

  @switches [
    topology: :string,
    hosts: :integer,
    agents: :integer,
    steps: :integer,
    mode: :string,
    group: :integer,
    strategy: :string,
    p: :float,
    latency_ms: :integer,
    loss: :float,
    seed: :integer,
    out: :string,
    until_covered: :boolean,
    keep_events: :boolean,
    dashboard: :integer,
    step_ms: :integer,
    time: :string,
    quiet: :boolean,
    json: :boolean,
    help: :boolean
  ]

  @impl true
  def run(argv) do
    opts = TartarusTools.CLI.parse!(argv, @switches, "tartarus.emu")
    if opts[:help], do: Mix.shell().info(@moduledoc), else: run_walk(check!(opts))
  end

  defp run_walk(opts) do
    Mix.Task.run("app.start")

    progress = Process.whereis(:standard_error)

    # Defaults are the walk's own (`TartarusEmu.Walk.schema/0`).
    defaults = for {k, spec} <- TartarusEmu.Walk.schema(), do: {k, spec[:default]}

    run_opts =
      defaults
      |> Keyword.merge(Keyword.take(opts, Keyword.keys(defaults)))
      |> Keyword.merge(
        latency_ms: opts[:latency_ms],
        loss: opts[:loss],
        # Seed 1 unless given, as every other task.
        seed: opts[:seed] || 1,
        out: Path.expand(opts[:out] || TartarusTools.Report.default_out_dir("walk")),
        quiet: opts[:quiet] || opts[:json] || false,
        progress_device: progress,
        dashboard: opts[:dashboard],
        step_ms: opts[:step_ms],
        time: opts[:time] && String.to_existing_atom(opts[:time])
      )
      |> Enum.reject(fn {_, v} -> is_nil(v) end)

    summary =
      case TartarusEmu.Walk.run(run_opts) do
        {:ok, summary} -> summary
        {:error, reason} -> TartarusTools.CLI.error!("tartarus.emu", reason)
      end

    unless opts[:json] do
      Mix.shell().info(
        "#{summary.hosts} hosts, #{summary.agents} agents, #{summary.steps} steps (#{summary.mode}): " <>
          "#{summary.migrations} migrations in #{summary.wall_ms} ms " <>
          "(#{summary.migrations_per_s}/s over the #{summary.steps_ms} ms inside the steps), coverage #{Float.round(summary.coverage * 1.0, 3)}, " <>
          "#{summary.energy_mj} mJ; results in #{run_opts[:out]}"
      )
    end

    if opts[:json], do: TartarusTools.CLI.report(summary, json: true)
  end

  defp check!(opts) do
    TartarusTools.CLI.positive!(opts, [:hosts, :agents, :steps, :group], "tartarus.emu")
    TartarusTools.CLI.probability!(opts, [:p, :loss], "tartarus.emu")
    TartarusTools.CLI.non_negative!(opts, [:dashboard, :step_ms], "tartarus.emu")

    case {opts[:time], opts[:mode]} do
      {t, _} when t not in [nil, "real", "virtual"] ->
        Mix.raise("mix tartarus.emu: --time: expected real or virtual, got: #{inspect(t)}")

      {"virtual", "peer"} ->
        Mix.raise(
          "mix tartarus.emu: --time virtual needs --mode virtual (networks of real BEAM nodes run in real time)"
        )

      _ ->
        :ok
    end

    case opts[:topology] do
      t when t in [nil, "grid", "ring", "line", "random"] ->
        :ok

      path ->
        unless File.regular?(path),
          do:
            Mix.raise(
              "mix tartarus.emu: --topology: file not found: #{path} " <>
                "(expected grid, ring, line, random or a topology file)"
            )
    end

    # Absent flags stay absent: the walk's schema supplies the defaults.
    choices = [mode: [:virtual, :peer], strategy: [:random, :conscientious]]

    Enum.reduce(choices, opts, fn {flag, values}, opts ->
      case TartarusTools.CLI.choice!(opts[flag], values, flag, "tartarus.emu", nil) do
        nil -> opts
        value -> Keyword.put(opts, flag, value)
      end
    end)
  end
end
