defmodule TartarusImmune.Evolution.Experiment.SharingSizes do
  @moduledoc """
  `sharing` of `mix tartarus.evolve` (thesis §7.4.3, Fig. 7.6): for each network size,
  social learning by broadcast (`b-cast`) against 1, 2, 4, ... intelligent packets
  (`iPkt-x`, x = n/20, n/10 and n/5, at least 1) and no sharing (`none`), `trials` runs
  each (`TartarusImmune.Evolution.Sharing`). A sweep (`TartarusEmu.Sweep`): an arm is a
  (size, scheme) point, `"<n>: <scheme>"`, the seeds `seed + trial`, the runs point by
  point. Run it with `TartarusImmune.Evolution.Experiment.run/1`.
  """

  import TartarusImmune.Evolution.Experiment.Shared,
    only: [mean2: 1, schemes: 1, label: 1, run_scheme: 4]

  alias TartarusTools.{Series, Stats, SVG}

  @doc "The sweep (arms, seeds, run, metrics, rows of `runs.csv`) for options `p`."
  @spec spec(map()) :: map()
  def spec(p) do
    %{
      arms: for({n, scheme} <- points_of(p), do: {"#{n}: #{label(scheme)}", {n, scheme}}),
      seeds: Enum.map(0..(p.trials - 1), &(p.seed + &1)),
      order: :arm_major,
      # peers are one set per run: one run at a time
      concurrency: if(p.mode == :peer, do: 1, else: System.schedulers_online()),
      run: fn arm, seed -> run_one(arm.opts, seed, p) end,
      metrics: [gamma_avg: :gamma_avg, omega: :omega],
      csv:
        {~w(nodes scheme trial gamma_avg omega first_solved_at converged_at iterations),
         fn run ->
           r = run.summary

           [
             [
               r.nodes,
               r.label,
               r.trial,
               r.gamma_avg,
               r.omega,
               r.first_solved_at,
               r.converged_at,
               r.iterations
             ]
           ]
         end}
    }
  end

  defp run_one({n, scheme}, seed, p),
    do: n |> run_scheme(scheme, seed, p) |> Map.put(:wall_ms, nil)

  defp points_of(p), do: for(n <- p.sizes, scheme <- schemes(n), do: {n, scheme})

  @doc "Points of the series: the (size, scheme) points."
  @spec points(map()) :: pos_integer()
  def points(p), do: length(points_of(p))

  @doc "Per size, the mean gamma_avg and Omega of each point (the step is the point's index)."
  @spec series([map()], map()) :: Series.t()
  def series(runs, p) do
    p
    |> points_of()
    |> Enum.with_index(1)
    |> Enum.reduce(Series.new(), fn {{n, scheme}, k}, series ->
      rs = of_point(runs, n, scheme)

      series
      |> Series.record(:"gamma_avg_n#{n}", k, mean2(Enum.map(rs, & &1.gamma_avg)))
      |> Series.record(:"omega_n#{n}", k, mean2(omegas(rs)))
    end)
  end

  defp of_point(runs, n, scheme),
    do: Enum.filter(runs, &(&1.nodes == n and &1.label == label(scheme)))

  @doc "Bar charts of gamma_avg and Omega per point (`runs.csv` is the sweep's)."
  @spec write(Path.t(), [map()], map()) :: [Path.t()]
  def write(dir, runs, p) do
    # A bar per point: the mean over its trials, with the mean's 95 % interval when there
    # are two trials or more.
    samples = fn key, runs ->
      if key == :gamma_avg, do: Enum.map(runs, & &1.gamma_avg), else: omegas(runs)
    end

    bars = fn key ->
      for {n, scheme} <- points_of(p) do
        xs = samples.(key, of_point(runs, n, scheme))
        bar = %{label: "#{n}: #{label(scheme)}", value: mean2(xs) || 0, n: length(xs)}

        case TartarusTools.Stats.mean_ci(xs) do
          %{lo: lo, hi: hi} when lo != nil -> Map.merge(bar, %{lo: lo, hi: hi})
          _ -> bar
        end
      end
    end

    opts = fn bars ->
      [
        subtitle: "sizes #{Enum.join(p.sizes, ", ")}; seeds #{p.seed}-#{p.seed + p.trials - 1}",
        note:
          if(Enum.any?(bars, &Map.has_key?(&1, :lo)),
            do: SVG.ci_note(Enum.map(bars, & &1.n), "trials", "bars"),
            else: "one trial per bar: no interval"
          )
      ]
    end

    gamma = Path.join(dir, "gamma_avg.svg")
    omega = Path.join(dir, "omega.svg")
    gamma_bars = bars.(:gamma_avg)
    omega_bars = bars.(:omega)

    File.write!(
      gamma,
      SVG.bar_chart(
        gamma_bars,
        [
          title: "Communications per node until convergence (gamma_avg, Fig. 7.6)",
          x_label: "nodes: scheme",
          y_label: "messages sent + received per node"
        ] ++ opts.(gamma_bars)
      )
    )

    File.write!(
      omega,
      SVG.bar_chart(
        omega_bars,
        [
          title: "Convergence count Omega: iterations from the first solution to 90% (Fig. 7.6)",
          x_label: "nodes: scheme",
          y_label: "iterations"
        ] ++ opts.(omega_bars)
      )
    )

    [gamma, omega]
  end

  @doc "The summary: per size and scheme, gamma_avg, Omega, convergence."
  @spec summary([map()], map()) :: map()
  def summary(runs, p) do
    by = fn f ->
      for {n, scheme} <- points_of(p), reduce: %{} do
        acc ->
          runs = Enum.filter(runs, &(&1.nodes == n and &1.label == label(scheme)))

          Map.update(
            acc,
            to_string(n),
            %{label(scheme) => f.(runs)},
            &Map.put(&1, label(scheme), f.(runs))
          )
      end
    end

    gamma = by.(fn runs -> mean2(Enum.map(runs, & &1.gamma_avg)) end)
    omega = by.(fn runs -> mean2(omegas(runs)) end)

    %{
      experiment: to_string(p.experiment),
      trials: p.trials,
      sizes: p.sizes,
      p: p.p,
      mode: to_string(p.mode),
      gamma_avg: gamma,
      omega: omega,
      omega_median: by.(fn runs -> Stats.median(omegas(runs)) end),
      converged_runs: by.(fn runs -> Enum.count(runs, & &1.converged) end),
      iterations_to_converge:
        by.(fn runs -> mean2(for r <- runs, r.converged, do: r.converged_at) end),
      ipkt_fewer_communications_at_every_size:
        Enum.all?(gamma, fn {_n, g} ->
          Enum.all?(g, fn {l, v} -> l in ["b-cast", "none"] or v < g["b-cast"] end)
        end),
      more_ipkts_lower_omega:
        Map.new(omega, fn {n, o} ->
          vs =
            o
            |> Enum.filter(&match?({"iPkt-" <> _, _}, &1))
            |> Enum.sort_by(&ipkts(elem(&1, 0)))
            |> Enum.map(&elem(&1, 1))

          {n, vs == Enum.sort(vs, :desc)}
        end),
      antibodies: nil,
      test_success: nil
    }
  end

  defp ipkts("iPkt-" <> x), do: String.to_integer(x)

  defp omegas(runs), do: for(r <- runs, r.omega != nil, do: r.omega)
end
