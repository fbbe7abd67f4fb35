defmodule TartarusArena.Sensitivity do
  @moduledoc """
  Table 6.5's sensitivity (`mix tartarus.arena --experiment sensitivity`, issue 46 item 8):
  the exhaustive per-sub-path ranking of `TartarusArena.Experiment` (every PFA alone over
  every sub-path instance of both paths, `TartarusArena.Run.subpath/4`; the PFA of least
  mean cost per sub-path type) under the three things the kinematic arena leaves out and
  docs/arena.md offered as the explanation of its A4, A4, A1, A1 against the thesis's A4,
  A2, A1, A2:

    * `kinematic` - the arena as it is (the reference);
    * `footprint` - line sensors that see a disc of radius `footprint` (m) instead of an
      8 mm spot (`TartarusArena.World`'s `line_footprint`);
    * `inertia` - wheels that reach their commanded speed at most `accel` m/s² (the
      robot option `accel`);
    * `rounded` - every corner of the paths rounded to `corner_radius` (m)
      (`TartarusArena.Paths.path/3`);
    * `all` - the three together.

  A `TartarusEmu.Sweep`: a condition is an arm, each seed one run of all eight PFAs over
  the nine sub-path instances under that condition (the seed sets the world's noise and
  the features' jitter, as in `mix tartarus.arena`). Pure apart from writing the outputs:
  the same seeds give the same numbers.

  **Judged** (pre-registered in docs/arena.md, "Table 6.5's sensitivity"): per condition,
  the least-cost PFA of each type over all its seeds' runs, and how many of the four
  types match Table 6.5 (`matches`). An explanation is supported (`supported`) when under
  its condition A2, the thesis's choice, becomes the least-cost PFA of the sharp turns
  (sp-b or sp-d), where the kinematic arena gives A4 and A1; the thesis's table is
  reproduced (`table6_5_reproduced`) when some condition matches all four types.
  """

  alias TartarusArena.{Paths, PFAs, Run}
  alias TartarusEmu.Sweep
  alias TartarusTools.{Report, Stats, SVG}

  @table6_5 %{sp_a: "A4", sp_b: "A2", sp_c: "A1", sp_d: "A2"}
  @conditions ~w(kinematic footprint inertia rounded all)

  @schema [
    seeds: [type: :pos_integer, default: 5, doc: "runs per condition (seeds seed, seed + 1, ...)"],
    seed: [type: :pos_integer, default: 1, doc: "first seed"],
    footprint: [
      type: {:range, 0.001, 0.05},
      default: 0.015,
      doc: "`footprint`, `all`: the line sensors' footprint radius (m)"
    ],
    accel: [
      type: {:range, 0.01, 100},
      default: 0.5,
      doc: "`inertia`, `all`: the wheels' acceleration limit (m/s²)"
    ],
    corner_radius: [
      type: {:range, 0.001, 0.075},
      default: 0.05,
      doc: "`rounded`, `all`: the radius of the paths' rounded corners (m)"
    ],
    pfas: [
      type: {:list, {:in, ~w(A1 A2 A3 A4 A5 A6 A7 A8)}},
      default: ~w(A1 A2 A3 A4 A5 A6 A7 A8),
      doc: "the PFAs ranked (all eight; fewer for a quick look)"
    ],
    out: [
      type: :any,
      doc: "output directory (default results/arena-sensitivity-<UTC time>), or false"
    ],
    quiet: [type: :boolean, default: false, doc: "no progress line per run"]
  ]

  @doc "The options' schema (`Tartarus.Options`)."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Table 6.5: the thesis's best PFA per sub-path type.

      iex> TartarusArena.Sensitivity.table6_5()[:sp_b]
      "A2"
  """
  @spec table6_5() :: %{Paths.type() => String.t()}
  def table6_5, do: @table6_5

  @doc """
  The conditions, in the order they are reported, with what each changes for options `o`
  (a map with `footprint`, `accel`, `corner_radius`): `{name, %{world:, robot:, paths:}}`.

      iex> [{"kinematic", k} | _] = TartarusArena.Sensitivity.conditions(%{footprint: 0.015, accel: 0.5, corner_radius: 0.05})
      iex> k
      %{paths: [], robot: [], world: []}
  """
  @spec conditions(map()) :: [{String.t(), map()}]
  def conditions(o) do
    for name <- @conditions do
      {name,
       %{
         world: if(name in ~w(footprint all), do: [line_footprint: o.footprint], else: []),
         robot: if(name in ~w(inertia all), do: [accel: o.accel], else: []),
         paths: if(name in ~w(rounded all), do: [corner_radius: o.corner_radius], else: [])
       }}
    end
  end

  @doc """
  Runs every condition on every seed. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, %{summary:, out:, files:}}` or `{:error, message}`.
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts \\ []) do
    with {:ok, opts} <-
           Tartarus.Options.validate(opts, @schema, "TartarusArena.Sensitivity.run/1") do
      o = Map.new(opts)
      seeds = Enum.to_list(o.seed..(o.seed + o.seeds - 1))
      out = Keyword.get_lazy(opts, :out, fn -> Report.default_out_dir("arena-sensitivity") end)

      spec = %{
        name: "arena-sensitivity",
        title: "Table 6.5's sensitivity: the exhaustive ranking under three arena changes",
        subtitle:
          "footprint #{o.footprint} m, accel #{o.accel} m/s², corner radius #{o.corner_radius} m",
        arms: conditions(o),
        seeds: seeds,
        order: :arm_major,
        run: fn arm, seed -> run_condition(arm.opts, seed, pfas(o)) end,
        metrics: [
          {:mean_cost, &Stats.mean(Enum.map(&1.subpaths, fn s -> s.cost end)),
           "mean cost over every PFA and sub-path instance (s)"},
          {:failed, &Enum.count(&1.subpaths, fn s -> not s.completed end),
           "failed sub-path runs (of 9 per PFA)"}
        ],
        csv:
          {~w(condition seed pfa path index type completed time on_line cost),
           fn run ->
             for s <- run.summary.subpaths,
                 do:
                   [run.arm, run.seed, s.pfa, s.path, s.index, s.type] ++
                     [s.completed, s.time, s.on_line, s.cost]
           end},
        summary: fn r -> summarize(r.runs, o, seeds) end,
        write: fn dir, r -> write(dir, summarize(r.runs, o, seeds), o, seeds) end,
        report: fn s -> [markdown: markdown(s)] end
      }

      {:ok, r} = Sweep.run(spec, out: out, quiet: o.quiet)
      {:ok, %{summary: r.summary, out: r.out, files: r.files}}
    end
  end

  # one condition, one seed: every PFA over every sub-path instance of both paths
  defp run_condition(c, seed, pfas) do
    paths = for id <- [1, 2], do: Paths.path(id, seed, c.paths)

    subs =
      for pfa <- pfas, p <- paths, sp <- p.subpaths do
        Run.subpath(pfa, p, sp.index, seed: seed, world: c.world, robot: c.robot)
      end

    %{subpaths: subs}
  end

  @doc """
  The summary of the runs: per condition the mean cost per type and PFA, the ranking per
  type (PFAs by mean cost), the least-cost PFA per type, the failures per type and PFA,
  the least-cost PFA per type on each seed, and `matches` (types agreeing with Table 6.5);
  then the pre-registered verdicts.
  """
  @spec summarize([map()], map(), [integer()]) :: map()
  def summarize(runs, o, seeds) do
    by_condition =
      for {name, _} <- conditions(o), into: %{} do
        rs = Enum.filter(runs, &(&1.arm == name))
        subs = Enum.flat_map(rs, & &1.summary.subpaths)
        cost = cost_table(subs, pfas(o))
        best = Map.new(cost, fn {type, m} -> {type, least(m)} end)

        per_seed =
          Map.new(rs, fn r ->
            {to_string(r.seed),
             Map.new(cost_table(r.summary.subpaths, pfas(o)), fn {t, m} -> {t, least(m)} end)}
          end)

        {name,
         %{
           cost: cost,
           ranking:
             Map.new(cost, fn {t, m} ->
               {t, m |> Enum.sort_by(&elem(&1, 1)) |> Enum.map(&elem(&1, 0))}
             end),
           best: best,
           failed:
             Map.new(Paths.types(), fn t ->
               {t,
                Map.new(pfas(o), fn pfa ->
                  n = PFAs.name(pfa)
                  {n, Enum.count(subs, &(&1.type == t and &1.pfa == n and not &1.completed))}
                end)}
             end),
           best_per_seed: per_seed,
           matches: Enum.count(best, fn {t, pfa} -> @table6_5[t] == pfa end)
         }}
      end

    %{
      experiment: "sensitivity",
      seeds: seeds,
      footprint: o.footprint,
      accel: o.accel,
      corner_radius: o.corner_radius,
      pfas: o.pfas,
      table6_5: @table6_5,
      conditions: by_condition,
      supported:
        Map.new(tl(@conditions), fn c ->
          {c, by_condition[c].best[:sp_b] == "A2" or by_condition[c].best[:sp_d] == "A2"}
        end),
      table6_5_reproduced: Enum.any?(by_condition, fn {_, c} -> c.matches == 4 end)
    }
  end

  defp pfas(o), do: Enum.map(o.pfas, &PFAs.by_name/1)

  defp cost_table(subs, pfas) do
    for type <- Paths.types(), into: %{} do
      {type,
       for pfa <- pfas, into: %{} do
         n = PFAs.name(pfa)
         cs = for s <- subs, s.type == type, s.pfa == n, do: s.cost
         {n, cs |> Stats.mean() |> Float.round(3)}
       end}
    end
  end

  defp least(m), do: m |> Enum.min_by(&elem(&1, 1)) |> elem(0)

  @doc """
  The tables in Markdown for summary `s`: the least-cost PFA per type and condition beside
  Table 6.5, then each condition's mean costs.
  """
  @spec markdown(map()) :: String.t()
  def markdown(s) do
    names = Enum.map(conditions(s), &elem(&1, 0))
    pfas = s.pfas

    best_rows =
      for t <- Paths.types() do
        "| #{t} | " <>
          Enum.map_join(names, " | ", &s.conditions[&1].best[t]) <> " | #{s.table6_5[t]} |"
      end

    cost_tables =
      for c <- names do
        rows =
          for t <- Paths.types() do
            cost = s.conditions[c].cost[t]
            fails = s.conditions[c].failed[t]

            "| #{t} | " <>
              Enum.map_join(pfas, " | ", fn p ->
                "#{cost[p]}" <> if(fails[p] > 0, do: " (#{fails[p]} failed)", else: "")
              end) <> " |"
          end

        """
        `#{c}`: mean cost per type (s; runs failed of #{length(s.seeds) * 2} or more):

        | type | #{Enum.join(pfas, " | ")} |
        |---|#{String.duplicate("---|", length(pfas))}
        #{Enum.join(rows, "\n")}
        """
      end

    """
    Least-cost PFA per sub-path type (seeds #{Enum.join(s.seeds, ", ")}; footprint #{s.footprint} m, accel #{s.accel} m/s², corner radius #{s.corner_radius} m):

    | type | #{Enum.join(names, " | ")} | Table 6.5 |
    |---|#{String.duplicate("---|", length(names))}---|
    #{Enum.join(best_rows, "\n")}
    | matches | #{Enum.map_join(names, " | ", &s.conditions[&1].matches)} | 4 |

    #{Enum.join(cost_tables, "\n")}
    """
  end

  defp write(dir, s, o, seeds) do
    names = Enum.map(conditions(o), &elem(&1, 0))

    cells =
      for t <- Paths.types(), c <- names ++ ["Table 6.5"], into: %{} do
        best = if c == "Table 6.5", do: s.table6_5[t], else: s.conditions[c].best[t]
        match = best == s.table6_5[t]
        {{to_string(t), c}, %{class: if(match, do: :same, else: :other), label: best}}
      end

    grid =
      SVG.grid_chart(Enum.map(Paths.types(), &to_string/1), names ++ ["Table 6.5"], cells,
        title: "Table 6.5's sensitivity: the least-cost PFA per sub-path type",
        subtitle:
          "footprint #{o.footprint} m, accel #{o.accel} m/s², corner radius #{o.corner_radius} m; seeds #{Enum.join(seeds, ", ")}",
        classes: [same: "as Table 6.5", other: "differs from Table 6.5"],
        x_label: "arena condition",
        y_label: "sub-path type",
        note: "a cell: the PFA of least mean cost over every instance and seed"
      )

    [SVG.write!(Path.join(dir, "ranking.svg"), grid)]
  end
end
