defmodule TartarusImmune.PathFollowing.Experiment.Summary do
  @moduledoc """
  The summary and the files of the path-following experiment
  (`TartarusImmune.PathFollowing.Experiment`, thesis §6.5.11) over its trials
  (`TartarusImmune.PathFollowing.Experiment.Trial`), and the exhaustive reference.

  ## Measures

  * `lap_times`: per path, the time of each lap (one list per trial) and the mean over
    trials per lap (Fig. 6.13 a and b);
  * `plateau_lap`: per path, on the mean curve, the first lap L such that every lap from
    L to the last is within 10% of the **final mean** (the mean of the last 3 laps); and
    `plateau_time`, the mean lap time from the plateau lap to the last;
    `plateau_lap_5pct` the same within 5% (on Path-1 the whole fall from a random PFA's
    lap to the best lap is about 14%, so a 10% band often holds from lap 1 or 2);
  * `best_pfa`: per sub-path type, the most frequent best PFA over the trials (ties: the
    earlier PFA), with `best_pfa_counts`;
  * `exhaustive_best`: per type, the PFA of least mean `score/2` over the type's
    instances on both paths (first trial's seed), with every PFA's mean
    (`exhaustive_costs`): the reference of trying everything;
  * `measured_costs`: per type and PFA, the mean normalized cost and the number of runs
    the robots measured in the laps of all trials (what the mechanism learned from), and
    `measured_best`, the PFA of least mean among those run at least 3 times;
  * `sim_speed_x`: simulated seconds (arena time summed over trials) per wall second of
    the trials (`wall_seconds`), the immune network included.
  """

  alias TartarusArena.{PFAs, Paths}
  alias TartarusImmune.{Domain, PathFollowing}
  alias TartarusTools.{Report, Stats, SVG}

  @thesis %{
    plateau_lap: %{"path1" => 6, "path2" => 8},
    plateau_time: %{"path1" => 22, "path2" => 31}
  }
  @table6_5 %{"sp_a" => "A4", "sp_b" => "A2", "sp_c" => "A1", "sp_d" => "A2"}

  # -- the exhaustive reference ----------------------------------------------------------

  @doc """
  Every PFA of `pfas` over every sub-path instance of both paths under `seed`
  (`PathFollowing.score/2`): per type, `{best_name, %{name => mean normalized cost}}`.
  """
  @spec exhaustive([module()], integer()) :: %{Paths.type() => {String.t(), map()}}
  def exhaustive(pfas, seed) do
    refs = for set <- [:p1, :p2], i <- 0..(PathFollowing.sets()[set] - 1), do: {set, i}

    by_type = Enum.group_by(refs, fn {set, i} -> PathFollowing.instance(set, i, seed).type end)

    Map.new(by_type, fn {type, rs} ->
      {best, means} = Domain.class_best(PathFollowing, pfas, rs, seed)

      {type,
       {PFAs.name(best), Map.new(means, fn {s, m} -> {PFAs.name(s), Float.round(m, 3)} end)}}
    end)
  end

  # -- summary ---------------------------------------------------------------------------

  # per path, over every crossing of every trial: put-backs, nudges, the seconds charged
  # for them, the crossings that had one, and the share of the robot's time those took
  defp failures(trials) do
    rows = Enum.flat_map(trials, & &1.choices)

    Map.new([{:r1, "path1"}, {:r2, "path2"}], fn {robot, key} ->
      rs = Enum.filter(rows, &(&1.robot == robot))
      failed = Enum.filter(rs, &(&1.put_back + &1.nudged > 0))
      total = rs |> Enum.map(& &1.time) |> Enum.sum()

      {key,
       %{
         crossings: length(rs),
         failed_crossings: length(failed),
         put_back: rs |> Enum.map(& &1.put_back) |> Enum.sum(),
         nudged: rs |> Enum.map(& &1.nudged) |> Enum.sum(),
         penalty_seconds: round3(rs |> Enum.map(& &1.penalty) |> Enum.sum()),
         failed_time_share: round3(Enum.sum(Enum.map(failed, & &1.time)) / max(total, 1.0e-9))
       }}
    end)
  end

  @doc """
  The plateau lap of a lap-time curve: the first lap L (1-based) such that every lap from
  L to the last is within `tol` (10%) of the mean of the last `tail` (3) laps.

      iex> TartarusImmune.PathFollowing.Experiment.Summary.plateau_lap([60, 40, 31, 29, 30, 30])
      3
      iex> TartarusImmune.PathFollowing.Experiment.Summary.plateau_lap([30, 30, 30])
      1
  """
  @spec plateau_lap([number()], number(), pos_integer()) :: pos_integer() | nil
  def plateau_lap(times, tol \\ 0.1, tail \\ 3)
  def plateau_lap([], _tol, _tail), do: nil

  def plateau_lap(times, tol, tail) do
    last = Enum.take(times, -tail)
    final = Stats.mean(last)
    n = length(times)

    times
    |> Enum.with_index(1)
    |> Enum.reverse()
    |> Enum.reduce_while(n, fn {t, i}, acc ->
      if abs(t - final) <= tol * final, do: {:cont, i}, else: {:halt, acc}
    end)
  end

  @doc """
  The numbers of one trial the sweep (`TartarusEmu.Sweep`'s `:metrics`) puts in
  `runs.csv`, describes over the trials and box-plots, per path (`_path1`, `_path2`):
  `last3` (the mean of the trial's last 3 laps, s), `plateau_lap` (`plateau_lap/3` of
  the trial's laps) and `lost` (times its robot was put back on the line or nudged on).
  """
  @spec metrics() :: [{atom(), (map() -> number() | nil), String.t()}]
  def metrics do
    per_path = [
      {"last3", "mean time of a trial's last 3 laps, s",
       fn t, id -> t.lap_times[id] |> Enum.take(-3) |> Stats.mean() |> round3() end},
      {"plateau_lap", "a trial's plateau lap", fn t, id -> plateau_lap(t.lap_times[id]) end},
      {"lost", "put back on the line or nudged on, per trial", fn t, id -> t.lost[id] end}
    ]

    for {id, key} <- [{1, "path1"}, {2, "path2"}], {name, title, f} <- per_path do
      {:"#{name}_#{key}", &f.(&1, id), "#{title} (Path-#{id})"}
    end
  end

  @doc """
  The summary of `trials` (in seed order) under options `o` (validated, `:pfas` set),
  with the exhaustive reference (`exhaustive/2`, or `nil`) and the trials' wall seconds:
  the keys of the module doc, the options and the thesis's figures.
  """
  @spec summarize(map(), [map()], map() | nil, float()) :: map()
  def summarize(o, trials, exhaustive, wall) do
    paths = [{1, "path1"}, {2, "path2"}]

    per_trial = Map.new(paths, fn {id, key} -> {key, Enum.map(trials, & &1.lap_times[id])} end)

    mean = Map.new(per_trial, fn {key, lists} -> {key, mean_curve(lists)} end)

    plateau = Map.new(mean, fn {k, c} -> {k, plateau_lap(c)} end)

    plateau_time =
      Map.new(mean, fn {k, c} ->
        case plateau[k] do
          nil -> {k, nil}
          l -> {k, round3(avg(Enum.drop(c, l - 1)))}
        end
      end)

    types = Enum.map(Paths.types(), &Atom.to_string/1)

    counts =
      Map.new(Paths.types(), fn type ->
        {Atom.to_string(type),
         trials |> Enum.map(& &1.best[type]) |> Enum.reject(&is_nil/1) |> Enum.frequencies()}
      end)

    order = Enum.map(o.pfas, &PFAs.name/1)

    best =
      Map.new(counts, fn {type, c} ->
        {type,
         case Enum.sort_by(c, fn {name, n} -> {-n, Enum.find_index(order, &(&1 == name))} end) do
           [] -> nil
           [{name, _} | _] -> name
         end}
      end)

    sim = trials |> Enum.map(& &1.sim_time) |> Enum.sum()

    # what the robots measured in the laps, over every trial: type -> PFA -> mean, count
    measured =
      trials
      |> Enum.flat_map(& &1.choices)
      |> Enum.group_by(&Atom.to_string(&1.type))
      |> Map.new(fn {type, rows} ->
        {type,
         rows
         |> Enum.group_by(& &1.pfa)
         |> Map.new(fn {pfa, rs} ->
           {pfa, %{mean: round3(avg(Enum.map(rs, & &1.cost))), runs: length(rs)}}
         end)}
      end)

    measured_best =
      Map.new(measured, fn {type, m} ->
        {type,
         m
         |> Enum.filter(fn {_, v} -> v.runs >= 3 end)
         |> Enum.min_by(fn {_, v} -> v.mean end, fn -> {nil, nil} end)
         |> elem(0)}
      end)

    ex =
      if exhaustive,
        do: Map.new(exhaustive, fn {t, {b, _}} -> {Atom.to_string(t), b} end),
        else: nil

    %{
      trials: o.trials,
      laps: o.laps,
      seed: o.seed,
      pfas: order,
      sharing: o.sharing,
      explore: o.explore,
      n_min: o.n_min,
      stream: o.stream,
      challenge: o.challenge,
      stuck_after: o.stuck_after,
      lost_penalty: o.lost_penalty,
      danger: o.danger,
      lap_times: %{
        "trial1" => Map.new(per_trial, fn {k, l} -> {k, hd(l)} end),
        "mean" => mean,
        "per_trial" => per_trial
      },
      plateau_lap: plateau,
      plateau_time: plateau_time,
      plateau_lap_5pct: Map.new(mean, fn {k, c} -> {k, plateau_lap(c, 0.05)} end),
      plateau_definition:
        "first lap L of the mean curve such that every lap from L on is within 10% of the mean of the last 3 laps",
      plateau_lap_per_trial:
        Map.new(per_trial, fn {k, lists} -> {k, Enum.map(lists, &plateau_lap/1)} end),
      best_pfa: best,
      best_pfa_counts: counts,
      best_pfa_table6_5: @table6_5,
      exhaustive_best: ex,
      exhaustive_costs:
        if(exhaustive, do: Map.new(exhaustive, fn {t, {_, m}} -> {Atom.to_string(t), m} end)),
      matches_exhaustive: if(ex, do: Map.new(types, &{&1, best[&1] == ex[&1]})),
      matches_table6_5: Map.new(types, &{&1, best[&1] == @table6_5[&1]}),
      measured_costs: measured,
      measured_best: measured_best,
      thesis: @thesis,
      lost_per_trial: Map.new(paths, fn {id, key} -> {key, Enum.map(trials, & &1.lost[id])} end),
      failures: failures(trials),
      counters:
        Enum.reduce(trials, %{}, fn t, acc ->
          Map.merge(acc, t.counters, fn _, a, b -> a + b end)
        end),
      sim_seconds: round3(sim),
      wall_seconds: round3(wall),
      sim_speed_x: round3(sim / max(wall, 1.0e-6))
    }
  end

  defp mean_curve(lists) do
    n = lists |> Enum.map(&length/1) |> Enum.min(fn -> 0 end)

    for i <- 0..(n - 1)//1 do
      lists |> Enum.map(&Enum.at(&1, i)) |> avg() |> round3()
    end
  end

  defp avg(xs), do: Stats.mean(xs) || 0.0
  defp round3(nil), do: nil
  defp round3(x), do: Float.round(x * 1.0, 3)

  # -- files -----------------------------------------------------------------------------

  @doc """
  Writes the experiment's own files into `out` for `trials` and their summary `s`:
  `lap_times.csv` (trial, seed, path, lap, seconds), `choices.csv` (every sub-path
  crossed), `best_pfa.csv` (Table 6.5 beside the thesis and the exhaustive search),
  `lap_times_trial1.svg` (Fig. 6.13a) and `lap_times_mean.svg` (Fig. 6.13b). Returns the
  paths written.
  """
  @spec write(Path.t(), map(), [map()], map()) :: [Path.t()]
  def write(out, o, trials, s) do
    File.mkdir_p!(out)

    lap_times =
      Report.write_csv!(
        out,
        "lap_times",
        ["trial", "seed", "path", "lap", "seconds"],
        for(
          {t, k} <- Enum.with_index(trials, 1),
          id <- [1, 2],
          {secs, lap} <- Enum.with_index(t.lap_times[id], 1),
          do: [k, t.seed, id, lap, secs]
        )
      )

    choices =
      Report.write_csv!(
        out,
        "choices",
        ~w(trial robot lap index type pfa how time on_line cost put_back nudged penalty),
        for(
          {t, k} <- Enum.with_index(trials, 1),
          c <- t.choices,
          do: [
            k,
            c.robot,
            c.lap,
            c.index,
            c.type,
            c.pfa,
            c.how,
            c.time,
            c.on_line,
            c.cost,
            c.put_back,
            c.nudged,
            c.penalty
          ]
        )
      )

    best =
      Report.write_csv!(
        out,
        "best_pfa",
        ["type", "best_pfa", "trials_per_pfa", "table6_5", "exhaustive_best"],
        for type <- Enum.map(Paths.types(), &Atom.to_string/1) do
          counts =
            s.best_pfa_counts[type]
            |> Enum.sort()
            |> Enum.map_join(" ", fn {n, c} -> "#{n}:#{c}" end)

          [
            type,
            s.best_pfa[type],
            counts,
            @table6_5[type],
            s.exhaustive_best && s.exhaustive_best[type]
          ]
        end
      )

    curve = fn lists ->
      for {key, label} <- [{"path1", "Path-1"}, {"path2", "Path-2"}] do
        %{
          name: label,
          points: Enum.with_index(lists[key], 1) |> Enum.map(fn {t, i} -> {i, t} end)
        }
      end
    end

    trial1 =
      SVG.write!(
        Path.join(out, "lap_times_trial1.svg"),
        SVG.line_chart(curve.(s.lap_times["trial1"]),
          title: "Time per lap, one trial (Fig. 6.13a)",
          subtitle: "seed #{o.seed}, #{o.laps} laps",
          x_label: "lap",
          y_label: "time per lap",
          y_unit: "s",
          y_min: 0
        )
      )

    # The mean curve with a 95 % interval over the trials at every lap.
    means =
      for {key, label} <- [{"path1", "Path-1"}, {"path2", "Path-2"}] do
        lists = s.lap_times["per_trial"][key]
        laps = lists |> Enum.map(&length/1) |> Enum.min(fn -> 0 end)

        SVG.mean_series(
          label,
          for(l <- 1..laps//1, do: {l, for(t <- lists, x = Enum.at(t, l - 1), do: x)})
        )
      end

    mean =
      SVG.write!(
        Path.join(out, "lap_times_mean.svg"),
        SVG.line_chart(means,
          title: "Mean time per lap over #{o.trials} trials (Fig. 6.13b)",
          subtitle: "seeds #{o.seed}-#{o.seed + o.trials - 1}, #{o.laps} laps",
          note:
            SVG.ci_note(Enum.flat_map(means, fn m -> Enum.map(m.n, &elem(&1, 1)) end), "trials"),
          x_label: "lap",
          y_label: "time per lap",
          y_unit: "s",
          y_min: 0
        )
      )

    charts = [trial1, mean]

    [lap_times, choices, best | charts]
  end

  @doc """
  What `summary.json` and `summary.md` show of summary `s` (`TartarusEmu.Sweep`'s
  `:report`): the summary with the mean lap times as `lap_times_mean` instead of every
  trial's (those are in `lap_times.csv`), and our plateau and best PFAs beside the
  thesis's (Fig. 6.13, Table 6.5).
  """
  @spec report(map()) :: keyword()
  def report(s) do
    [
      summary: Map.delete(s, :lap_times) |> Map.put(:lap_times_mean, s.lap_times["mean"]),
      comparisons: [
        %{metric: "plateau lap, Path-1", ours: s.plateau_lap["path1"], thesis: 6},
        %{metric: "plateau lap, Path-2", ours: s.plateau_lap["path2"], thesis: 8},
        %{metric: "plateau time, Path-1 (s)", ours: s.plateau_time["path1"], thesis: 22},
        %{metric: "plateau time, Path-2 (s)", ours: s.plateau_time["path2"], thesis: 31}
        | for type <- ["sp_a", "sp_b", "sp_c", "sp_d"] do
            %{
              metric: "best PFA #{type}",
              ours: s.best_pfa[type],
              thesis: @table6_5[type],
              note: "exhaustive search here: #{s.exhaustive_best && s.exhaustive_best[type]}"
            }
          end
      ]
    ]
  end
end
