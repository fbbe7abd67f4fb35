defmodule Mix.Tasks.Tartarus.Roadblock do
  @shortdoc "Roadblock rescue: a mobile agent chooses and programs a rescue robot (thesis §2.4)"
  @moduledoc """
  Runs the roadblock scenario of thesis §2.4 on the arena (see `TartarusRoadblock` and
  docs/roadblock.md): Santa meets a block on its path, the monitoring node's webcam
  snapshot goes to the administrator, who releases a mobile agent with the rescue program;
  the agent forages for a rescue robot, chooses Claus (claws) over Rudolph (pusher),
  installs the program on Claus, which takes the block off the path and goes back to its
  dock; Santa drives on to B.

      mix tartarus.roadblock [--auto] [--mode virtual|peer] [--seed 1] [--out DIR] [--json]
                             [--block-at 2] [--steps 2400] [--dashboard PORT]

  Without `--auto` the run waits for the administrator when the snapshot arrives:

    * in iex (`iex -S mix tartarus.roadblock --seed 1`), the run goes on in the
      background and the shell is yours: `TartarusRoadblock.snapshot("snapshot.png")`
      writes the snapshot, `TartarusRoadblock.release_rescue()` releases the rescue
      agent, `TartarusRoadblock.await()` returns the result;
    * otherwise the task asks on the terminal and releases the agent when you press Enter.

  `--dashboard PORT` serves the web dashboard on 127.0.0.1:PORT (the address and token
  are printed) with the roadblock panel: Santa, the rescue, the latest events, the webcam
  snapshot, and (without `--auto`) a button that releases the rescue agent, so the
  administrator can decide from the page instead of the terminal.

  `--mode peer` runs every host on a BEAM node of its own (`:peer`); `--help` prints this
  text.

  Output (in `--out DIR`, default `results/roadblock-<UTC timestamp>`): `snapshot.png`
  (the webcam's picture), `trajectories.svg` (the robots' paths over the arena),
  `timeline.csv` and `timeline.svg` (who did what, arena time and wall clock),
  `santa_x` and `claus_to_block` series (CSV, SVG), `summary.json`, `summary.md`.

  Summary keys: `rescued, chosen_robot, santa_arrived, agent_hops, seconds` (arena time)
  and the others listed in `TartarusRoadblock.run/1`. With `--json` the last line printed
  is the summary as one JSON object.
  """
  use TartarusTools.CLI

  alias Tartarus.Clock

  @task "tartarus.roadblock"

  @impl true
  def run(argv) do
    schema =
      TartarusRoadblock.schema()
      |> Keyword.drop([:quiet])
      |> Keyword.update!(:auto, &Keyword.put(&1, :default, false))
      |> Keyword.update!(:out, &Keyword.put(&1, :type, :string))
      |> Keyword.update!(:dashboard, &Keyword.put(&1, :type, :non_neg_integer))
      |> Keyword.put(:json, type: :boolean, default: false, doc: "print the summary as JSON")

    opts = TartarusTools.CLI.options!(argv, schema, @task)
    {mode, json?} = {opts[:mode], opts[:json]}
    run_opts = Keyword.drop(opts, [:json])

    case TartarusRoadblock.validate(run_opts) do
      {:ok, _} -> :ok
      {:error, message} -> TartarusTools.CLI.error!(@task, message)
    end

    Mix.Task.run("app.start")

    cond do
      opts[:auto] ->
        unless json?, do: Mix.shell().info("roadblock: seed #{opts[:seed]}, #{mode} hosts...")
        report(TartarusRoadblock.run(run_opts), json?)

      iex?() ->
        {:ok, _} = TartarusRoadblock.start(run_opts)

        Mix.shell().info(
          "roadblock: running in the background (seed #{opts[:seed]}, #{mode} hosts); " <>
            "when Santa is blocked, release the rescue agent with TartarusRoadblock.release_rescue()"
        )

      opts[:dashboard] ->
        {:ok, _} = TartarusRoadblock.start(run_opts)

        Mix.shell().info(
          "roadblock: when Santa is blocked, release the rescue agent from the dashboard's roadblock panel"
        )

        report(TartarusRoadblock.await(:infinity), json?)

      true ->
        {:ok, _} = TartarusRoadblock.start(run_opts)
        wait_for_blocked()
        IO.gets("press Enter to release the rescue agent> ")
        {:ok, _} = TartarusRoadblock.release_rescue()
        report(TartarusRoadblock.await(), json?)
    end
  end

  defp iex?, do: Code.ensure_loaded?(IEx) and IEx.started?()

  # The run prints its message when Santa is blocked; wait until it waits for us.
  defp wait_for_blocked do
    if Process.whereis(TartarusRoadblock.Driver) &&
         match?({:ok, _}, TartarusRoadblock.snapshot(Path.join(System.tmp_dir!(), "rb.png"))) do
      :ok
    else
      Clock.sleep(100)
      wait_for_blocked()
    end
  end

  defp report({:ok, %{summary: s, out: dir}}, json?) do
    TartarusTools.CLI.report(s, [json: json?], fn s -> text(s) <> "\nwritten to #{dir}" end)
  end

  defp report({:error, message}, _json?), do: TartarusTools.CLI.error!(@task, message)

  @doc false
  # The run's outcome for a person: what happened, and what did not (a run cut short by
  # --steps has no robot chosen and no arrival, and says so rather than printing blanks).
  @spec text(map()) :: String.t()
  def text(s) do
    rescue_line =
      if s.chosen_robot do
        candidates = Enum.map_join(s.candidates, ", ", &"#{&1.robot} #{inspect(&1.capabilities)}")

        "rescued #{s.rescued} by #{s.chosen_robot} (candidates: #{candidates})"
      else
        "no robot chosen: the run ended at #{show(s.seconds)} s of arena time " <>
          "(#{s.steps} steps of 0.05 s), before the rescue; raise --steps (default 2400)"
      end

    santa =
      if s.santa_arrived,
        do: "Santa arrived at #{show(s.santa_arrival_s)} s",
        else: "Santa did not arrive"

    """
    #{rescue_line}
    #{santa} (stopped #{show(s.santa_stopped_s)} s); rescue agent #{s.agent_hops} hops over #{s.hosts_visited} hosts\
    """
  end

  defp show(x), do: TartarusTools.CLI.show(x)
end
