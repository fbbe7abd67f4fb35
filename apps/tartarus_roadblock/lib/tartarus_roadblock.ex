defmodule TartarusRoadblock do
  @moduledoc """
  The roadblock rescue of thesis §2.4, on the arena: a cyber-physical system of 13 Tartarus
  hosts (12 computers and a Pi with a webcam beside the path, the monitoring node), the
  commuter robot Santa on a line path from A to B, and two rescue robots on their dock:
  Rudolph (a pusher) and Claus (claws).

  A block appears on the path. Santa's ultrasonic sensor sees it; Santa stops and tells the
  monitoring node, whose static agent takes a snapshot with its webcam (a PNG) and forwards
  it to the administrator's host. The administrator (a person in iex, or `auto: true`)
  releases a mobile agent carrying the rescue program as code; it forages the network for
  rescue robots, compares Rudolph and Claus by their capabilities against its requirement
  (`[:drive, :claws]`), goes to Claus's host and installs the program there; Claus drives
  to the block, takes it off the path, and the agent guides Claus back to its dock. Santa
  drives on to B. See `docs/roadblock.md`.

      {:ok, %{summary: s}} = TartarusRoadblock.run(seed: 1, out: false)
      s.rescued and s.chosen_robot == "claus" and s.santa_arrived   #=> true

  ## The administrator in iex

      TartarusRoadblock.start(seed: 1, out: "results/roadblock-iex")
      # ... Santa stops; a message says the snapshot is at the administrator's host
      TartarusRoadblock.snapshot("snapshot.png")     # {:ok, report}
      TartarusRoadblock.release_rescue()             # {:ok, agent_id}
      TartarusRoadblock.await()                      # {:ok, %{summary: ...}}

  (`iex -S mix tartarus.roadblock --seed 1` does the first line for you; the README has a
  transcript.) With `dashboard: port` the web dashboard shows the run and its panel
  (`TartarusRoadblock.Panel`): the snapshot, and a button that releases the rescue agent.

  Modules: `TartarusRoadblock.Scenario` (the `TartarusEmu.Scenario`), the agents
  `TartarusRoadblock.Commuter`, `TartarusRoadblock.Monitor`, `TartarusRoadblock.Admin`,
  `TartarusRoadblock.Rescuer`, and the program `TartarusRoadblock.RescueProgram`; the
  devices are the arena's `TartarusArena.RobotPlugin`, `TartarusArena.DevicePlugin` and
  `TartarusArena.CameraPlugin`.
  """

  alias Tartarus.Clock
  alias TartarusArena.World

  require Tartarus.Clock

  @schema [
    seed: [type: :integer, default: 1, doc: "seed of the arena's noise and the block's place"],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    auto: [
      type: :boolean,
      default: true,
      doc: "release the rescue agent at once (false: wait for `release_rescue/1`)"
    ],
    block_at: [type: :pos_integer, default: 2, doc: "arena seconds until the block appears"],
    steps: [type: :pos_integer, default: 2400, doc: "control steps of 0.05 s at most"],
    out: [
      type: :any,
      doc: "output directory (default `results/roadblock-<stamp>`), `false` for none"
    ],
    quiet: [type: :boolean, default: true, doc: "no progress line"],
    dashboard: [
      type: :any,
      doc:
        "serve the web dashboard on this port (127.0.0.1) while the run goes, or dashboard options (`port:`, `token:`, ... of `TartarusDashboard`), with the roadblock panel (`TartarusRoadblock.Panel`: the snapshot, and a button that releases the rescue agent)"
    ]
  ]

  @doc """
  The options of `run/1` and `start/1`:

  #{Tartarus.Options.docs(@schema)}
  """
  @spec schema() :: keyword()
  def schema, do: @schema

  @doc "Checks options against `schema/0`: `{:ok, opts}` or `{:error, message}`."
  @spec validate(keyword()) :: {:ok, keyword()} | {:error, String.t()}
  def validate(opts), do: Tartarus.Options.validate(opts, @schema, "TartarusRoadblock.run/1")

  @doc """
  Runs the scenario (see the moduledoc) and writes its outputs: `snapshot.png`,
  `trajectories.svg`, `timeline.csv`, `timeline.svg`, the series, `summary.json` and
  `summary.md`. Returns `{:ok, %{summary:, out:, files:, series:}}` (see
  `TartarusEmu.Scenario.run/2`) or `{:error, message}`.

  Summary keys: `rescued` (the block is off the path and the program finished),
  `chosen_robot`, `santa_arrived`, `agent_hops` (the rescue agent's migrations), `seconds`
  (arena time), `santa_arrival_s`, `santa_stopped_s`, `rescue_done_s`, `claus_docked`,
  `block`, `block_final`, `candidates`, `requirement`, `hosts_visited`, `nodes`, `mode`,
  `snapshot_bytes`, `release_to_install_ms` (wall time of the agent's walk), and the
  runner's `scenario, seed, steps, setup_ms, run_ms`.
  """
  @spec run(keyword()) :: {:ok, TartarusEmu.Scenario.result()} | {:error, term()}
  def run(opts \\ []) do
    with {:ok, opts} <- validate(opts),
         :ok <- distributed(opts[:mode]) do
      {block_at, opts} = Keyword.pop(opts, :block_at)
      opts = if Keyword.get(opts, :out) == nil, do: Keyword.delete(opts, :out), else: opts
      TartarusEmu.Scenario.run(TartarusRoadblock.Scenario, [{:block_at, block_at * 1.0} | opts])
    end
  end

  defp distributed(:peer) do
    case TartarusTools.Peer.ensure_distributed("roadblock") do
      :ok -> :ok
      {:error, reason} -> {:error, "peer mode needs a distributed node: #{inspect(reason)}"}
    end
  end

  defp distributed(_), do: :ok

  @doc """
  Starts a run in the background for an administrator in iex (`auto: false` unless given;
  other options as `run/1`) and returns `{:ok, pid}`. When Santa is blocked it prints
  where, and waits for `release_rescue/1`; `await/1` gets the result.
  """
  @spec start(keyword()) :: {:ok, pid()} | {:error, String.t()}
  def start(opts \\ []) do
    opts = Keyword.put_new(opts, :auto, false)

    with {:ok, _} <- validate(opts) do
      pid = spawn(fn -> serve_result(run(opts)) end)
      :persistent_term.put({__MODULE__, :run}, pid)
      {:ok, pid}
    end
  end

  # The background run answers await/1 (from any process) until 10 minutes pass without a
  # request: minutes of the machine's time (a person's, in iex), which in virtual time would
  # go by at once while the VM waits for that person.
  defp serve_result(result) do
    tag = make_ref()
    timer = Clock.machine_send_after(self(), {:roadblock_served, tag}, 600_000)

    receive do
      {:roadblock_await, from, ref} ->
        Clock.cancel_timer(timer)
        send(from, {ref, result})
        serve_result(result)

      {:roadblock_served, ^tag} ->
        :ok
    end
  end

  @doc """
  The administrator releases the rescue agent, from iex, while a run started by `start/1`
  waits. Options: `requirement:` the capabilities the rescue robot must have (default
  `[:drive, :claws]`). Returns `{:ok, agent_id}`, or `{:error, :no_run_waiting}` when no
  run is going on. Called before Santa is blocked, it waits (up to 60 s) until the run
  gets there; a release that times out is still taken when the run gets there.
  """
  @spec release_rescue(keyword()) :: {:ok, String.t()} | {:error, :no_run_waiting}
  defdelegate release_rescue(opts \\ []), to: TartarusRoadblock.Control, as: :release

  @doc """
  Waits (up to `timeout` ms, default 120 s) for the run last started by `start/1` (from
  any process) and returns its result as `run/1` does, or `{:error, :timeout}` (or
  `{:error, :no_run}`).
  """
  @spec await(timeout()) :: {:ok, map()} | {:error, term()}
  def await(timeout \\ 120_000) do
    with pid when is_pid(pid) <- :persistent_term.get({__MODULE__, :run}, nil),
         ref = Process.monitor(pid),
         _ = send(pid, {:roadblock_await, self(), ref}) do
      Clock.receive do
        {^ref, result} ->
          Process.demonitor(ref, [:flush])
          result

        {:DOWN, ^ref, :process, _, reason} ->
          {:error, {:run_down, reason}}
      after
        timeout -> {:error, :timeout}
      end
    else
      nil -> {:error, :no_run}
    end
  end

  @doc """
  The snapshot the monitoring node sent to the administrator's host, written to `path`;
  returns `{:ok, report}` (where Santa is, what it measured, the block's estimated place)
  or `{:error, :no_snapshot}` (no run going on, or none waiting for the administrator
  within 15 s).
  """
  @spec snapshot(Path.t()) :: {:ok, map()} | {:error, :no_snapshot}
  def snapshot(path) do
    with pid when is_pid(pid) <- Process.whereis(TartarusRoadblock.Driver),
         ref = make_ref(),
         _ = send(pid, {:roadblock_snapshot_request, self(), ref}),
         {png, report} when is_binary(png) <- await_reply(ref) do
      File.write!(path, png)
      {:ok, report}
    else
      _ -> {:error, :no_snapshot}
    end
  end

  defp await_reply(ref) do
    Clock.receive do
      {^ref, reply} -> reply
    after
      15_000 -> nil
    end
  end

  @doc "The network of the scenario: see `TartarusRoadblock.Site.topology/0`."
  @spec topology() :: TartarusEmu.Topology.t()
  defdelegate topology(), to: TartarusRoadblock.Site

  @doc "The arena of the scenario for a seed, and its layout: see `TartarusRoadblock.Site.world/1`."
  @spec world(integer()) :: {World.t(), map()}
  defdelegate world(seed), to: TartarusRoadblock.Site
end
