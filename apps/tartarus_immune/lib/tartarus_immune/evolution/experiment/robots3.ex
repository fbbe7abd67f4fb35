defmodule TartarusImmune.Evolution.Experiment.Robots3 do
  @moduledoc """
  `robots3` and `robots3_dynamic` of `mix tartarus.evolve` (thesis §7.4.2): three robots
  learning S3 in one arena, sharing antibodies by broadcast, by a packet agent, or not at
  all (`TartarusImmune.Evolution.Collective`), on the same seeds. A sweep
  (`TartarusEmu.Sweep`): the arms are the schemes `none`, `broadcast`, `ipkt` on a static
  full mesh and, for `robots3_dynamic` (issue 46), `broadcast_dynamic` and `ipkt_dynamic`
  on the same mesh with links that come and go (`dynamic: p`, `p` the experiment's
  option, a tick every 3 s); the seeds `seed + trial`; `runs.csv` has a row per robot and
  run. Run it with `TartarusImmune.Evolution.Experiment.run/1`.
  """

  import TartarusImmune.Evolution.Experiment.Shared, only: [mean2: 1]

  alias TartarusImmune.Evolution.Collective
  alias TartarusTools.{Series, Stats, SVG}

  @doc """
  The arms of options `p`: label => {scheme, link flap probability}.

      iex> TartarusImmune.Evolution.Experiment.Robots3.arms(%{experiment: :robots3, p: 0.1})
      [{"none", {:none, 0.0}}, {"broadcast", {:broadcast, 0.0}}, {"ipkt", {:ipkt, 0.0}}]
      iex> TartarusImmune.Evolution.Experiment.Robots3.arms(%{experiment: :robots3_dynamic, p: 0.1}) |> Enum.map(&elem(&1, 0))
      ["none", "broadcast", "ipkt", "broadcast_dynamic", "ipkt_dynamic"]
  """
  @spec arms(map()) :: [{String.t(), {atom(), float()}}]
  def arms(p) do
    static = for s <- [:none, :broadcast, :ipkt], do: {to_string(s), {s, 0.0}}

    if p.experiment == :robots3_dynamic,
      do: static ++ for(s <- [:broadcast, :ipkt], do: {"#{s}_dynamic", {s, p.p * 1.0}}),
      else: static
  end

  @doc "The sweep (arms, seeds, run, metrics, tests, rows of `runs.csv`) for options `p`."
  @spec spec(map()) :: map()
  def spec(p) do
    exact = [method: :exact]

    tests =
      if p.experiment == :robots3_dynamic,
        do:
          for(
            a <- ["broadcast_dynamic", "ipkt_dynamic"],
            do: {a, :greater, "none", :test_success, exact}
          ) ++
            for(
              s <- ["broadcast", "ipkt"],
              do: {s, :greater, "#{s}_dynamic", :test_success, exact}
            ),
        else: []

    %{
      arms: arms(p),
      seeds: Enum.map(0..(p.trials - 1), &(p.seed + &1)),
      run: fn arm, seed ->
        {scheme, dyn} = arm.opts

        {:ok, r} =
          Collective.run(scheme: scheme, seed: seed, puck_reward: p.puck_reward, dynamic: dyn)

        Map.merge(r, %{trial: seed - p.seed, arm: arm.name})
      end,
      metrics: [
        test_success: :test_success,
        external_selections: fn r ->
          Stats.mean(Enum.map(r.per_robot, & &1.external_selections))
        end
      ],
      tests: tests,
      csv:
        {~w(scheme trial robot antibodies external_selections test_success communications),
         fn run ->
           r = run.summary
           c = r.communications

           for p <- r.per_robot do
             [
               r.arm,
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
      Series.record(series, :"test_success_robots3_#{r.arm}", r.trial + 1, r.test_success)
    end)
  end

  @doc "`robots3_dynamic`: test success per arm (`robots3_dynamic.svg`); `robots3`: none."
  @spec write(Path.t(), [map()], map()) :: [Path.t()]
  def write(dir, runs, %{experiment: :robots3_dynamic} = p) do
    groups =
      for {label, _} <- arms(p) do
        rs = Enum.filter(runs, &(&1.arm == label))
        chosen = Stats.mean(for r <- rs, q <- r.per_robot, do: q.external_selections) || 0.0

        {"#{label} (#{Float.round(chosen * 1.0, 1)} shared chosen)",
         Enum.map(rs, & &1.test_success)}
      end

    file = Path.join(dir, "robots3_dynamic.svg")

    File.write!(
      file,
      SVG.box_plot(groups,
        title:
          "S3, three robots: sharing on a static mesh and with links that come and go (p = #{p.p} per 3 s), seeds #{p.seed}-#{p.seed + p.trials - 1}",
        y_label: "test success (mean over the three robots)"
      )
    )

    [file]
  end

  def write(_dir, _runs, _p), do: []

  @doc "The summary: per scheme, test success, antibodies, shared antibodies chosen, communications."
  @spec summary([map()], map()) :: map()
  def summary(runs, p) do
    by = fn f ->
      Map.new(arms(p), fn {label, _} -> {label, f.(Enum.filter(runs, &(&1.arm == label)))} end)
    end

    comm = fn r -> r.communications |> Map.values() |> Enum.sum() end
    per = fn runs, k -> mean2(for r <- runs, q <- r.per_robot, do: Map.fetch!(q, k)) end
    success = fn label -> for r <- runs, r.arm == label, do: r.test_success end

    tests =
      for {a, b} <- [
            {"broadcast_dynamic", "none"},
            {"ipkt_dynamic", "none"},
            {"broadcast", "none"},
            {"ipkt", "none"},
            {"broadcast", "broadcast_dynamic"},
            {"ipkt", "ipkt_dynamic"}
          ],
          success.(a) != [] and success.(b) != [],
          into: %{} do
        t = Stats.mann_whitney(success.(a), success.(b), method: :exact)
        {"#{a} > #{b}", Float.round(t.p_value, 4)}
      end

    %{
      experiment: to_string(p.experiment),
      trials: p.trials,
      seeds: [p.seed, p.seed + p.trials - 1],
      p: if(p.experiment == :robots3_dynamic, do: p.p),
      puck_reward: to_string(p.puck_reward),
      p_values: tests,
      publications_per_robot: by.(&per.(&1, :publications)),
      reached_per_publication:
        by.(fn runs ->
          pubs = for r <- runs, q <- r.per_robot, do: q.publications
          reached = for r <- runs, q <- r.per_robot, do: q.reached
          if Enum.sum(pubs) > 0, do: Float.round(Enum.sum(reached) / Enum.sum(pubs), 3)
        end),
      packet_stays_per_robot: by.(&per.(&1, :stays)),
      links_up: by.(fn runs -> mean2(Enum.map(runs, & &1.links_up)) end),
      link_flaps: by.(fn runs -> mean2(Enum.map(runs, & &1.link_flaps)) end),
      test_success: by.(fn runs -> mean2(Enum.map(runs, & &1.test_success)) end),
      antibodies: by.(fn runs -> mean2(for r <- runs, p <- r.per_robot, do: p.antibodies) end),
      external_selections:
        by.(fn runs -> mean2(for r <- runs, p <- r.per_robot, do: p.external_selections) end),
      communications_per_robot: by.(fn runs -> mean2(for r <- runs, do: comm.(r) / r.robots) end)
    }
  end
end
