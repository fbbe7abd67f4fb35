defmodule TartarusImmune.Evolution.Experiment.Robots3 do
  @moduledoc """
  `robots3` of `mix tartarus.evolve` (thesis §7.4.2): three robots learning S3 in one
  arena, sharing antibodies by broadcast, by a packet agent, or not at all
  (`TartarusImmune.Evolution.Collective`), on the same seeds. A sweep
  (`TartarusEmu.Sweep`): the arms are the schemes `none`, `broadcast`, `ipkt`, the seeds
  `seed + trial`; `runs.csv` has a row per robot and run. Run it with
  `TartarusImmune.Evolution.Experiment.run/1`.
  """

  import TartarusImmune.Evolution.Experiment.Shared, only: [mean2: 1]

  alias TartarusImmune.Evolution.Collective
  alias TartarusTools.Series

  @schemes [:none, :broadcast, :ipkt]

  @doc "The sweep (arms, seeds, run, metrics, rows of `runs.csv`) for options `p`."
  @spec spec(map()) :: map()
  def spec(p) do
    %{
      arms: Enum.map(@schemes, &{to_string(&1), &1}),
      seeds: Enum.map(0..(p.trials - 1), &(p.seed + &1)),
      run: fn arm, seed ->
        {:ok, r} = Collective.run(scheme: arm.opts, seed: seed, puck_reward: p.puck_reward)
        Map.put(r, :trial, seed - p.seed)
      end,
      metrics: [test_success: :test_success],
      csv:
        {~w(scheme trial robot antibodies external_selections test_success communications),
         fn run ->
           r = run.summary
           c = r.communications

           for p <- r.per_robot do
             [
               r.scheme,
               r.trial,
               p.robot,
               p.antibodies,
               p.external_selections,
               p.test_success,
               c.broadcast_messages + c.broadcasts_received + c.departures + c.arrivals
             ]
           end
         end}
    }
  end

  @doc "Points of the series: the trials."
  @spec points(map()) :: pos_integer()
  def points(p), do: p.trials

  @doc "Test success per trial, one series per scheme."
  @spec series([map()], map()) :: Series.t()
  def series(runs, _p) do
    Enum.reduce(runs, Series.new(), fn r, series ->
      Series.record(series, :"test_success_robots3_#{r.scheme}", r.trial + 1, r.test_success)
    end)
  end

  @doc "No files besides the sweep's."
  @spec write(Path.t(), [map()], map()) :: [Path.t()]
  def write(_dir, _runs, _p), do: []

  @doc "The summary: per scheme, test success, antibodies, shared antibodies chosen, communications."
  @spec summary([map()], map()) :: map()
  def summary(runs, p) do
    by = fn f ->
      Map.new([:none, :broadcast, :ipkt], fn scheme ->
        {to_string(scheme), f.(Enum.filter(runs, &(&1.scheme == scheme)))}
      end)
    end

    comm = fn r -> r.communications |> Map.values() |> Enum.sum() end

    %{
      experiment: "robots3",
      trials: p.trials,
      puck_reward: to_string(p.puck_reward),
      test_success: by.(fn runs -> mean2(Enum.map(runs, & &1.test_success)) end),
      antibodies: by.(fn runs -> mean2(for r <- runs, p <- r.per_robot, do: p.antibodies) end),
      external_selections:
        by.(fn runs -> mean2(for r <- runs, p <- r.per_robot, do: p.external_selections) end),
      communications_per_robot: by.(fn runs -> mean2(for r <- runs, do: comm.(r) / r.robots) end)
    }
  end
end
