# Issue 46, item 3: reads the summaries of the registered runs in docs/warehouse.md ("Figs.
# 4.11 and 4.13, §4.5.5's m·t, §4.3's MANET") and draws
#
#   docs/warehouse/fig411_mixed.svg        Fig. 4.11: seed 4611, a row per job (copied)
#   docs/warehouse/fig411_span.svg         each job's span over its tasks' times, every seed
#   docs/warehouse/fig413_removal.svg      Fig. 4.13: seed 4621, a row per job (copied)
#   docs/warehouse/fig413_utilisation.svg  each robot's utilisation before r2 left, between,
#                                          after r4 joined, every seed
#   docs/warehouse/fig455_mt.svg           §4.5.5: makespan over m·t per arm, every seed
#   docs/warehouse/manet.svg               §4.3: makespan per churn p, every seed
#
# and prints, as JSON, the numbers of the note and each registered criterion's verdict.
#
#   mix run docs/warehouse/issue46.exs DIR
#
# DIR holds `<name>.log` (the run's output, its last line the summary: `--json`) and
# `<name>/` (its output directory) for name in mixed, removal, concurrent, manet.
[dir] = System.argv()

alias TartarusTools.{JSON, Stats, SVG}

summary = fn name ->
  dir
  |> Path.join("#{name}.log")
  |> File.read!()
  |> String.split("\n", trim: true)
  |> List.last()
  |> JSON.decode!()
end

out = Path.join(File.cwd!(), "docs/warehouse")
copy = fn from, to -> File.cp!(Path.join(dir, from), Path.join(out, to)) end
median = fn xs -> Float.round(Stats.median_mid(xs) * 1.0, 3) end

# -- Fig. 4.11 -----------------------------------------------------------------------------
mixed = summary.("mixed")
mseeds = Enum.map(mixed["seeds"], &to_string/1)
copy.("mixed/gantt_mixed_seed_#{hd(mseeds)}_by_job.svg", "fig411_mixed.svg")
ratio = fn j -> for s <- mseeds, do: mixed["span_over_serial"][s][to_string(j)] end

SVG.write!(
  Path.join(out, "fig411_span.svg"),
  SVG.box_plot(Enum.map(1..6, &{"J#{&1}", ratio.(&1)}),
    title: "Fig. 4.11: each job's span over its tasks' times",
    subtitle:
      "6 jobs on 4 robots, J1 and J6 sequential, J2-J5 two independent sequences; seeds #{hd(mseeds)}-#{List.last(mseeds)}, virtual time, L = 10 ms",
    y_label: "span / sum of task times",
    y_min: 0
  )
)

mixed_ratios = Enum.flat_map(2..5, ratio)

overlapping =
  mseeds |> Enum.map(&length(mixed["jobs_with_concurrent_sequences"][&1])) |> Enum.sum()

seq_ok =
  Enum.all?(mseeds, fn s ->
    Enum.all?(["1", "6"], fn j ->
      length(mixed["robots_per_job"][s][j]) == 1 and mixed["span_over_serial"][s][j] >= 1.0
    end)
  end)

# -- Fig. 4.13 -----------------------------------------------------------------------------
removal = summary.("removal")
rseeds = Enum.map(removal["seeds"], &to_string/1)
copy.("removal/gantt_removal_seed_#{hd(rseeds)}_by_job.svg", "fig413_removal.svg")
phases = ["before", "between", "after"]
u = fn phase, robot, s -> removal["utilisation_#{phase}"][s][robot] end

groups =
  for robot <- ~w(r1 r2 r3 r4), phase <- phases do
    {"#{robot} #{phase}", for(s <- rseeds, v = u.(phase, robot, s), v != nil, do: v)}
  end

SVG.write!(
  Path.join(out, "fig413_utilisation.svg"),
  SVG.box_plot(groups,
    title: "Fig. 4.13: each robot's utilisation before r2 left, without it, after r4 joined",
    subtitle:
      "10 jobs of T1-T4 on r1-r3, r2 retires after 2 jobs, r4 joins after 6; seeds #{hd(rseeds)}-#{List.last(rseeds)}, virtual time",
    y_label: "busy fraction",
    y_min: 0
  )
)

between_sum = for s <- rseeds, do: u.("between", "r1", s) + u.("between", "r3", s)

rise =
  Map.new(~w(r1 r3), fn r ->
    {r, median.(for s <- rseeds, do: u.("between", r, s) - u.("before", r, s))}
  end)

r4_jobs = for s <- rseeds, do: length(removal["jobs_per_robot"][s]["r4"])

# job spans before r2 left (jobs 1-2) and after
spans = fn jobs -> for s <- rseeds, j <- jobs, do: removal["job_span_ms"][s][to_string(j)] end

# -- §4.5.5 --------------------------------------------------------------------------------
conc = summary.("concurrent")
arms = ["n=2 k=2", "n=2 k=4", "n=4 k=4", "n=4 k=8", "n=8 k=8", "n=8 k=16"]
over = fn arm -> for {_, m} <- conc["concurrency"][arm]["by_seed"], do: m["over_mt"] end

SVG.write!(
  Path.join(out, "fig455_mt.svg"),
  SVG.box_plot(Enum.map(arms, &{&1, over.(&1)}),
    title: "§4.5.5: the makespan of m jobs of n independent tasks over m·t",
    subtitle:
      "m = 10 jobs, t = 2,000 ms, k robots; L = 10 ms, S = 5 ms; seeds #{Enum.join(conc["seeds"], ", ")}, virtual time",
    y_label: "makespan / m·t",
    y_min: 1
  )
)

conc_peaks =
  Map.new(arms, fn arm ->
    {arm, for({_, m} <- conc["concurrency"][arm]["by_seed"], do: m["peak"]) |> Enum.uniq()}
  end)

# -- §4.3's MANET --------------------------------------------------------------------------
manet = summary.("manet")
parms = Enum.map(manet["churn"], &"p=#{&1}")
field = fn arm, key -> for {_, m} <- manet["manet"][arm]["by_seed"], do: m[key] end

SVG.write!(
  Path.join(out, "manet.svg"),
  SVG.box_plot(
    Enum.map(parms, &{&1, Enum.map(field.(&1, "makespan_ms"), fn ms -> ms / 1000 end)}),
    title: "§4.3: 12 jobs while robots and Σ nodes leave and rejoin the network",
    subtitle:
      "6 robots linked only through 6 Σ nodes and jd; a node up leaves with p a 500 ms tick, rejoins with 1/2; seeds #{Enum.join(manet["seeds"], ", ")}, virtual time",
    y_label: "makespan",
    y_unit: "s",
    y_min: 0
  )
)

copy.("manet/gantt_manet.svg", "manet_gantt.svg")

manet_table =
  Map.new(parms, fn arm ->
    a = manet["manet"][arm]

    {arm,
     %{
       jobs: a["jobs"],
       done: a["done"],
       not_done_reported: a["not_done_reported"],
       violations: a["violations"],
       disconnections: a["disconnections_applied"],
       makespan_s_median: median.(field.(arm, "makespan_ms")) / 1000,
       down_fraction_median: median.(field.(arm, "down_fraction")),
       migrations_median: median.(field.(arm, "migrations")),
       arrivals_at_sigma_median: median.(field.(arm, "arrivals_at_sigma"))
     }}
  end)

manet_floors = for arm <- parms, {_, m} <- manet["manet"][arm]["by_seed"], do: m

IO.puts(
  JSON.encode!(%{
    mixed: %{
      census: Map.take(mixed, ["jobs", "completed_jobs", "mutex_violations"]),
      overlapping_of_40: overlapping,
      overlapping_by_seed: mixed["jobs_with_concurrent_sequences"],
      span_over_serial_median_by_job: Map.new(1..6, &{"J#{&1}", median.(ratio.(&1))}),
      span_over_serial_median_mixed: median.(mixed_ratios),
      span_ms_median_by_job:
        Map.new(1..6, fn j ->
          {"J#{j}", median.(for s <- mseeds, do: mixed["job_span_ms"][s][to_string(j)])}
        end),
      one_robot_mixed_jobs:
        for(
          s <- mseeds,
          j <- 2..5,
          length(mixed["robots_per_job"][s][to_string(j)]) == 1,
          do: "#{s}/J#{j}"
        ),
      utilisation_median:
        Map.new(~w(r1 r2 r3 r4), fn r ->
          {r, median.(for s <- mseeds, do: mixed["utilisation"][s][r])}
        end),
      criteria: %{
        m1: seq_ok,
        m2: overlapping >= 20 and median.(mixed_ratios) < 1,
        m3: mixed["mutex_violations"] == 0 and mixed["completed_jobs"] == 60
      }
    },
    removal: %{
      census: Map.take(removal, ["jobs", "completed_jobs", "mutex_violations"]),
      jobs_per_robot: removal["jobs_per_robot"],
      utilisation_median:
        Map.new(for(r <- ~w(r1 r2 r3 r4), p <- phases, do: {r, p}), fn {r, p} ->
          vs = for s <- rseeds, v = u.(p, r, s), v != nil, do: v
          {"#{r} #{p}", median.(vs)}
        end),
      between_r1_plus_r3: between_sum,
      rise_median: rise,
      r4_jobs: r4_jobs,
      span_ms_median_jobs_1_2: median.(spans.(1..2)),
      span_ms_median_jobs_3_10: median.(spans.(3..10)),
      phase_ms: removal["phase_ms"],
      criteria: %{
        r1: Enum.all?(rseeds, &(removal["r2_jobs_after_retire"][&1] == [])),
        r2: Enum.all?(between_sum, &(&1 > 1)),
        r3: Enum.all?(Map.values(rise), &(&1 >= 0)),
        r4: Enum.all?(r4_jobs, &(&1 >= 1)),
        r5: removal["mutex_violations"] == 0 and removal["completed_jobs"] == 100
      }
    },
    concurrent: %{
      census: Map.take(conc, ["jobs", "completed_jobs", "mutex_violations"]),
      over_mt_median: Map.new(arms, &{&1, conc["concurrency"][&1]["over_mt"]}),
      over_mt_range: Map.new(arms, &{&1, Enum.min_max(over.(&1)) |> Tuple.to_list()}),
      mean_running_median: Map.new(arms, &{&1, conc["concurrency"][&1]["mean_running"]}),
      peaks: conc_peaks,
      criteria: %{
        c1:
          Enum.all?(arms, fn arm ->
            conc_peaks[arm] == [String.to_integer(Regex.run(~r/n=(\d+)/, arm) |> List.last())]
          end),
        c2: Map.new(arms, &{&1, conc["concurrency"][&1]["over_mt"] <= 1.10}),
        c3: conc["mutex_violations"] == 0 and conc["completed_jobs"] == conc["jobs"]
      }
    },
    manet: %{
      census: Map.take(manet, ["jobs", "completed_jobs", "mutex_violations"]),
      by_arm: manet_table,
      criteria: %{
        n1: Enum.all?(manet_floors, &(&1["violations"] == 0)),
        n2: Enum.all?(manet_floors, &(&1["done"] + &1["not_done_reported"] == &1["jobs"])),
        n3: Enum.all?(manet_floors, &(&1["done"] == &1["jobs"]))
      }
    }
  })
)
