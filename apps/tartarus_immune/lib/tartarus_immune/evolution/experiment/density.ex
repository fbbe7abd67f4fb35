defmodule TartarusImmune.Evolution.Experiment.Density do
  @moduledoc """
  `density` of `mix tartarus.evolve` (thesis ch. 8: "The results favored the utilization
  of mobile agents when the network is dense and suggested the use of broadcasting for
  sparse networks"): the sharing experiment of §7.4.3 (`TartarusImmune.Evolution.Sharing`)
  over a sweep of network density at fixed node counts. For each size `n` in `sizes` and
  each `degree` in `degrees` (link stubs per node: the potential neighbours at most, 5 in
  Fig. 7.6; half of the links are live in the long run), broadcast (`b-cast`) against
  iPkts in the three numbers of Fig. 7.6 (n/20, n/10, n/5), `trials` runs each on seeds
  `seed + trial`. A sweep (`TartarusEmu.Sweep`): an arm is a (size, degree, scheme) point,
  `"n<n> d<degree>: <scheme>"`.

  **Measured** per run: `gamma_avg` (communications per node until convergence, the
  thesis's energy measure), `omega`, `converged_at` (iterations to 90 % solved),
  `potential_degree` (mean degree of the potential graph) and `mean_degree` (live
  neighbours per node averaged over the run's iterations).

  **Judged** (pre-registered in docs/evolution.md, "Dense versus sparse"): per size and
  degree, the ratio `R = mean gamma_avg(iPkt-n/10) / mean gamma_avg(b-cast)` and two
  one-sided Mann-Whitney U tests of the runs' gamma_avg (b-cast lower; iPkt lower). The
  claim is reproduced at a size when at the sparsest degree broadcast needs fewer
  communications (p < 0.05) and at the densest iPkts do (p < 0.05). The crossover is the
  live mean degree where `R` crosses 1, interpolated linearly between the two degrees
  around it (`nil` when `R` stays on one side). The other iPkt counts are reported the
  same way, not judged.
  """

  import TartarusImmune.Evolution.Experiment.Shared, only: [mean2: 1, label: 1, run_scheme: 5]

  alias TartarusTools.{Series, Stats, SVG}

  @doc """
  The schemes compared at size `n`: broadcast and iPkts in Fig. 7.6's three numbers.

      iex> TartarusImmune.Evolution.Experiment.Density.schemes(40)
      [:broadcast, {:ipkt, 2}, {:ipkt, 4}, {:ipkt, 8}]
  """
  @spec schemes(pos_integer()) :: [:broadcast | {:ipkt, pos_integer()}]
  def schemes(n), do: tl(TartarusImmune.Evolution.Experiment.Shared.schemes(n))

  @doc "The iPkt count judged at size `n`: n/10 (at least 1)."
  @spec judged(pos_integer()) :: pos_integer()
  def judged(n), do: max(1, div(n, 10))

  @doc """
  The name of the arm of size `n`, degree `d` and `scheme`.

      iex> TartarusImmune.Evolution.Experiment.Density.arm(40, 3, {:ipkt, 4})
      "n40 d3: iPkt-4"
  """
  @spec arm(pos_integer(), pos_integer(), term()) :: String.t()
  def arm(n, d, scheme), do: "n#{n} d#{d}: #{label(scheme)}"

  @doc "The sweep (arms, seeds, run, metrics, rows of `runs.csv`) for options `p`."
  @spec spec(map()) :: map()
  def spec(p) do
    %{
      arms: for({n, d, scheme} <- points_of(p), do: {arm(n, d, scheme), {n, d, scheme}}),
      seeds: Enum.map(0..(p.trials - 1), &(p.seed + &1)),
      order: :arm_major,
      concurrency: if(p.mode == :peer, do: 1, else: System.schedulers_online()),
      run: fn arm, seed -> run_one(arm.opts, seed, p) end,
      metrics: [
        gamma_avg: :gamma_avg,
        omega: :omega,
        converged_at: :converged_at,
        mean_degree: :mean_degree
      ],
      csv:
        {~w(nodes degree scheme trial potential_degree mean_degree gamma_avg omega first_solved_at converged_at iterations),
         fn run ->
           r = run.summary

           [
             [
               r.nodes,
               r.degree,
               r.label,
               r.trial,
               r.potential_degree,
               r.mean_degree,
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

  defp run_one({n, d, scheme}, seed, p),
    do: n |> run_scheme(scheme, seed, p, degree: d) |> Map.delete(:solved)

  defp points_of(p),
    do: for(n <- p.sizes, d <- p.degrees, scheme <- schemes(n), do: {n, d, scheme})

  @doc "Points of the series: the (size, degree, scheme) points."
  @spec points(map()) :: pos_integer()
  def points(p), do: length(points_of(p))

  defp of_point(runs, n, d, scheme),
    do: Enum.filter(runs, &(&1.nodes == n and &1.degree == d and &1.label == label(scheme)))

  defp gammas(runs), do: Enum.map(runs, & &1.gamma_avg)

  # the live mean degree of (n, d): over every run of every scheme there
  defp live_degree(runs, n, d),
    do: mean2(for r <- runs, r.nodes == n, r.degree == d, do: r.mean_degree)

  @doc """
  Per size and iPkt scheme, the ratio of mean gamma_avg (iPkt over b-cast) against the
  live mean degree (the step is the degree's index).
  """
  @spec series([map()], map()) :: Series.t()
  def series(runs, p) do
    for n <- p.sizes,
        {:ipkt, x} = scheme <- tl(schemes(n)),
        {d, k} <- Enum.with_index(p.degrees, 1),
        reduce: Series.new() do
      series ->
        Series.record(series, :"ratio_n#{n}_ipkt#{x}", k, ratio(runs, n, d, scheme))
    end
  end

  defp ratio(runs, n, d, scheme) do
    b = Stats.mean(gammas(of_point(runs, n, d, :broadcast)))
    i = Stats.mean(gammas(of_point(runs, n, d, scheme)))
    if b && i && b > 0, do: Float.round(i / b, 3)
  end

  @doc """
  Where `ratios` (`[{degree, ratio}]`, by increasing degree) cross 1: the degree
  interpolated linearly between the two points around the first crossing, or `nil`.

      iex> TartarusImmune.Evolution.Experiment.Density.crossover([{1.0, 1.5}, {2.0, 0.5}])
      1.5
      iex> TartarusImmune.Evolution.Experiment.Density.crossover([{1.0, 0.3}, {2.0, 0.5}])
      nil
  """
  @spec crossover([{number(), number() | nil}]) :: float() | nil
  def crossover(ratios) do
    ratios
    |> Enum.reject(&is_nil(elem(&1, 1)))
    |> Enum.chunk_every(2, 1, :discard)
    |> Enum.find_value(fn [{d1, r1}, {d2, r2}] ->
      if (r1 - 1) * (r2 - 1) <= 0 and r1 != r2,
        do: Float.round(d1 + (1 - r1) / (r2 - r1) * (d2 - d1), 2)
    end)
  end

  @doc "Charts: the ratio iPkt/b-cast and gamma_avg per scheme, against the live mean degree."
  @spec write(Path.t(), [map()], map()) :: [Path.t()]
  def write(dir, runs, p) do
    subtitle =
      "n #{Enum.join(p.sizes, ", ")}; stubs per node #{Enum.join(p.degrees, ", ")}; " <>
        "p #{p.p}; seeds #{p.seed}-#{p.seed + p.trials - 1}"

    ratio_series =
      for n <- p.sizes, {:ipkt, x} = scheme <- tl(schemes(n)) do
        pts =
          for d <- p.degrees,
              r = ratio(runs, n, d, scheme),
              do: {live_degree(runs, n, d), r}

        %{name: "n #{n}: iPkt-#{x} / b-cast", points: pts}
      end

    ratio_svg = Path.join(dir, "density_ratio.svg")

    File.write!(
      ratio_svg,
      SVG.line_chart(ratio_series,
        title: "Communications per node, iPkts over broadcast, against density",
        subtitle: subtitle,
        x_label: "live neighbours per node (mean over the run)",
        y_label: "gamma_avg(iPkt) / gamma_avg(b-cast)",
        y_min: 0,
        references: [
          %{
            name: "equal cost (above: broadcast cheaper)",
            points: [{0, 1.0}, {max_degree(runs), 1.0}]
          }
        ],
        note: "each point: mean gamma_avg of #{p.trials} runs over the mean of #{p.trials}"
      )
    )

    gamma_series =
      for n <- p.sizes, scheme <- schemes(n) do
        SVG.mean_series(
          "n #{n}: #{label(scheme)}",
          for(d <- p.degrees, do: {live_degree(runs, n, d), gammas(of_point(runs, n, d, scheme))})
        )
      end

    gamma_svg = Path.join(dir, "density_gamma.svg")

    File.write!(
      gamma_svg,
      SVG.line_chart(gamma_series,
        title: "Communications per node until convergence (gamma_avg) against density",
        subtitle: subtitle,
        x_label: "live neighbours per node (mean over the run)",
        y_label: "messages sent + received per node",
        y_min: 0,
        note: SVG.ci_note([p.trials], "runs")
      )
    )

    [ratio_svg, gamma_svg]
  end

  defp max_degree(runs), do: runs |> Enum.map(& &1.mean_degree) |> Enum.max(fn -> 1 end)

  @doc """
  The summary: per size (string keys) and degree, the live degree, gamma_avg, Omega and
  iterations to converge per scheme, the ratios and tests, the crossover per iPkt count,
  and the pre-registered verdict `claim_reproduced` per size.
  """
  @spec summary([map()], map()) :: map()
  def summary(runs, p) do
    per_size =
      Map.new(p.sizes, fn n ->
        x = judged(n)

        by_degree =
          for d <- p.degrees, into: %{} do
            b = gammas(of_point(runs, n, d, :broadcast))
            i = gammas(of_point(runs, n, d, {:ipkt, x}))

            per_scheme = fn f ->
              Map.new(schemes(n), &{label(&1), f.(of_point(runs, n, d, &1))})
            end

            {to_string(d),
             %{
               potential_degree:
                 mean2(for r <- runs, r.nodes == n, r.degree == d, do: r.potential_degree),
               live_degree: live_degree(runs, n, d),
               gamma_avg: per_scheme.(&mean2(gammas(&1))),
               omega: per_scheme.(&mean2(for r <- &1, r.omega != nil, do: r.omega)),
               converged_at:
                 per_scheme.(&mean2(for r <- &1, r.converged_at != nil, do: r.converged_at)),
               converged_runs: per_scheme.(&Enum.count(&1, fn r -> r.converged end)),
               ratio: Map.new(tl(schemes(n)), &{label(&1), ratio(runs, n, d, &1)}),
               p_bcast_fewer: p_value(b, i),
               p_ipkt_fewer: p_value(i, b)
             }}
          end

        crossovers =
          Map.new(tl(schemes(n)), fn scheme ->
            {label(scheme),
             crossover(
               for d <- p.degrees,
                   do: {live_degree(runs, n, d), ratio(runs, n, d, scheme)}
             )}
          end)

        sparse = by_degree[to_string(Enum.min(p.degrees))]
        dense = by_degree[to_string(Enum.max(p.degrees))]

        {to_string(n),
         %{
           judged: "iPkt-#{x}",
           by_degree: by_degree,
           crossover: crossovers,
           bcast_fewer_at_sparsest: sparse.p_bcast_fewer < 0.05,
           ipkt_fewer_at_densest: dense.p_ipkt_fewer < 0.05,
           claim_reproduced: sparse.p_bcast_fewer < 0.05 and dense.p_ipkt_fewer < 0.05
         }}
      end)

    %{
      experiment: to_string(p.experiment),
      trials: p.trials,
      sizes: p.sizes,
      degrees: p.degrees,
      p: p.p,
      mode: to_string(p.mode),
      seeds: "#{p.seed}-#{p.seed + p.trials - 1}",
      density: per_size,
      claim_reproduced: Map.new(per_size, fn {n, s} -> {n, s.claim_reproduced} end)
    }
  end

  defp p_value(xs, ys) do
    p = Stats.mann_whitney(xs, ys, alternative: :less).p_value
    Float.round(p, 4)
  end
end
