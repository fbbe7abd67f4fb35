defmodule TartarusLats.Replay.Experiment do
  @moduledoc """
  The real-data comparison as a `TartarusEmu.Sweep`: every track (a log file: one arm)
  replayed with every seed (`TartarusLats.Replay.run/2`), the per-track figures of LATS and
  both baselines pooled over the seeds, the pass criterion of docs/lats.md checked, and the
  files written (`TartarusLats.Replay.Report`, the floor plan, and the sweep's `runs.csv`,
  `summary.json`, `summary.md`). `mix tartarus.lats --replay-log` runs it.
  """

  alias TartarusLats.Replay
  alias TartarusLats.Replay.{Calibration, Devices, Report}

  # The designs judged, in the order of the outputs (the fingerprinting baseline only with
  # reference points).
  @designs [:lats, :thesis, :strongest, :knn]

  # Bad lines listed (line number and why) per track in the summary.
  @bad_listed 100

  @schema [
    logs: [type: {:list, :string}, required: true, doc: "the log files, one track each"],
    devices: [type: :string, required: true, doc: "the devices file"],
    calibration: [type: :string, doc: "a calibration file (`TartarusLats.Replay.Calibration`)"],
    fingerprints: [
      type: :string,
      doc: "a directory of reference recordings, for the kNN baseline"
    ],
    floor_plan: [type: :string, doc: "a floor-plan file instead of the devices' Delaunay graph"],
    seed: [type: :integer, default: 1, doc: "first seed"],
    seeds: [type: :pos_integer, default: 3, doc: "seeds per track"],
    queries: [type: :pos_integer, default: 10, doc: "query instants per track and seed"],
    mode: [type: {:in, [:virtual, :peer]}, default: :virtual, doc: "where hosts run"],
    group: [type: :pos_integer, default: 6, doc: "nodes per BEAM node (peer mode)"],
    window: [type: :pos_integer, doc: "the trackers' and baselines' window (s)"],
    repair: [
      type: :boolean,
      default: true,
      doc: "Where is X and Trace agents bridge broken chains"
    ],
    replay: [
      type: :keyword,
      default: [],
      doc:
        "further options of `TartarusLats.Replay.run/2` (for instance `zone:`), for trying a configuration"
    ],
    out: [type: :any, doc: "output directory (`false`: none)"],
    quiet: [type: :boolean, default: false, doc: "no progress lines"]
  ]

  @doc "The options of `run/1`."
  @spec schema() :: keyword()
  def schema, do: @schema

  @doc """
  Runs the comparison. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, %{summary:, out:}}` (the summary holds per track and design the pooled
  figures under `:tracks`, and `:pass`) or `{:error, message}`.
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts) do
    with {:ok, opts} <-
           Tartarus.Options.validate(opts, @schema, "TartarusLats.Replay.Experiment"),
         {:ok, devices} <- load(fn -> Devices.read!(opts[:devices]) end, "--devices") do
      cal = if opts[:calibration], do: Calibration.read!(opts[:calibration])

      points =
        if opts[:fingerprints], do: Calibration.points(opts[:fingerprints], devices), else: []

      cases =
        for log <- opts[:logs] do
          c = Replay.prepare(log, devices)

          if opts[:floor_plan] do
            b = Devices.read_floor_plan!(opts[:floor_plan])
            %{c | building: b, truth: TartarusLats.Replay.Judge.truth(b, c.positions, c.last)}
          else
            c
          end
        end

      warmup = Keyword.get(opts[:replay], :warmup, Replay.schema()[:warmup][:default])

      case Enum.find_value(cases, &error(Replay.check(&1, warmup))) do
        nil -> sweep(cases, cal, points, opts)
        message -> {:error, message}
      end
    end
  end

  defp error(:ok), do: nil
  defp error({:error, message}), do: message

  defp sweep(cases, cal, points, opts) do
    designs = if points == [], do: @designs -- [:knn], else: @designs

    run_opts =
      [
        calibration: cal,
        fingerprints: points,
        queries: opts[:queries],
        mode: opts[:mode],
        group: opts[:group],
        repair: opts[:repair]
      ] ++ if(opts[:window], do: [window: opts[:window]], else: []) ++ opts[:replay]

    spec = %{
      name: "lats-replay",
      title: "LATS on real BLE recordings",
      arms: Enum.map(cases, &{&1.name, &1}),
      seeds: opts[:seed]..(opts[:seed] + opts[:seeds] - 1),
      concurrency: 1,
      run: fn arm, seed ->
        r = Replay.run(arm.opts, [seed: seed] ++ run_opts)
        {flat(r.summary), r}
      end,
      metrics:
        for(
          d <- designs,
          k <- [:exact, :adjacent, :where_is_correct, :trace_edit_mean],
          do: {:"#{d}_#{k}", :"#{d}_#{k}"}
        ),
      summary: fn result -> pooled(result.runs, cases, cal) end,
      write: fn dir, result ->
        plan = Path.join(dir, "floor_plan.txt")
        Devices.write_floor_plan!(plan, hd(cases).building)

        [plan] ++
          Enum.flat_map(cases, fn c ->
            runs = for r <- result.runs, r.arm == c.name, do: r.data
            Report.write!(dir, c, runs)
          end)
      end,
      report: fn summary -> [summary: summary, markdown: markdown(summary)] end
    }

    {:ok, result} = TartarusEmu.Sweep.run(spec, out: Keyword.get(opts, :out), quiet: opts[:quiet])

    {:ok, %{summary: result.summary, out: result.out}}
  end

  defp load(fun, flag) do
    {:ok, fun.()}
  rescue
    e in [File.Error, ArgumentError] -> {:error, "#{flag}: #{Exception.message(e)}"}
  end

  defp flat(summary) do
    per =
      for d <- @designs,
          Map.has_key?(summary, d),
          {k, v} <- summary[d],
          into: %{},
          do: {:"#{d}_#{k}", v}

    summary |> Map.drop(@designs) |> Map.drop([:unknown_receivers]) |> Map.merge(per)
  end

  # Per track, pooled over the seeds: the rates (the same every seed: the decisions do not
  # depend on the seed), Where is X correct of asked, mean Trace edit distance, cloud
  # connections (summed over the seeds' queries for LATS; per run for the cloud).
  defp pooled(runs, cases, cal) do
    tracks =
      Map.new(cases, fn c ->
        rs = for r <- runs, r.arm == c.name, do: r.data

        per =
          @designs
          |> Enum.filter(&Map.has_key?(hd(rs).summary, &1))
          |> Map.new(fn d ->
            s0 = hd(rs).summary[d]
            tr = for r <- rs, q <- r.queries, q.type == :trace, do: q.judged[d].edit_distance
            wi = for r <- rs, q <- r.queries, q.type == :where_is, do: q.judged[d].correct

            {d,
             %{
               exact: s0.exact,
               adjacent: s0.adjacent,
               changes: s0.changes,
               true_changes: s0.true_changes,
               where_is: length(wi),
               where_is_correct: Enum.count(wi, & &1),
               traces: length(tr),
               trace_edit_mean: TartarusTools.Stats.mean(tr),
               trace_edit_median: TartarusTools.Stats.median(tr),
               cloud_connections_per_run: s0.cloud_connections
             }}
          end)

        l = per.lats
        s = per.strongest

        # Nothing measured is no pass (nil >= nil would be).
        pass = %{
          exact: at_least(l.exact, s.exact),
          adjacent: at_least(l.adjacent, s.adjacent),
          where_is: at_least(l.where_is_correct, s.where_is_correct),
          trace: at_least(s.trace_edit_mean, l.trace_edit_mean)
        }

        {c.name,
         Map.merge(per, %{
           seconds: c.last,
           holders:
             Map.take(hd(rs).summary, [
               :holders_at_once,
               :seconds_with_two_holders,
               :changes,
               :non_neighbour_jumps,
               :non_neighbour_jumps_without_release
             ]),
           log_lines: c.lines,
           log_bad_lines: length(c.bad),
           bad_lines: for({no, why} <- Enum.take(c.bad, @bad_listed), do: %{line: no, why: why}),
           log_unterminated_line: c.unterminated,
           unknown_receivers: c.unknown_receivers,
           pass: pass,
           lats_cloud_per_query:
             Enum.sum(for r <- rs, do: r.summary.cloud_connections_lats_per_query)
         })}
      end)

    %{
      tracks: tracks,
      repair: hd(runs).summary.repair,
      calibration: if(cal, do: cal.kind, else: :none),
      pass: Enum.all?(tracks, fn {_, t} -> Enum.all?(Map.values(t.pass)) end)
    }
  end

  defp at_least(a, b) when is_number(a) and is_number(b), do: a >= b
  defp at_least(_a, _b), do: false

  defp markdown(summary) do
    header =
      "| track | design | exact | adjacent | zone changes (true) | Where is X correct | Trace edit distance (mean) | cloud connections |\n|---|---|---|---|---|---|---|---|\n"

    rows =
      for {name, t} <- Enum.sort(summary.tracks), d <- @designs, t[d] do
        x = t[d]

        "| #{name} | #{d} | #{pct(x.exact)} | #{pct(x.adjacent)} | #{x.changes} (#{x.true_changes}) | #{x.where_is_correct}/#{x.where_is} | #{round2(x.trace_edit_mean)} | #{x.cloud_connections_per_run} |\n"
      end

    input =
      for {name, t} <- Enum.sort(summary.tracks),
          line <- input_lines(t),
          do: "* #{name}: #{line}\n"

    "## Per track (seeds pooled)\n\n" <>
      header <>
      Enum.join(rows) <>
      "\npass: #{summary.pass}\n" <>
      if(input == [], do: "", else: "\n## Input\n\n" <> Enum.join(input))
  end

  @doc """
  What a track's log held that was not replayed, one line each (for the task's output and
  `summary.md`): bad lines with their numbers and why (the first ten; `summary.json` lists
  the first #{@bad_listed}), a last line without a newline, readings of receivers that the
  devices file does not name. `t` is a track of the summary's `:tracks`.
  """
  @spec input_lines(map()) :: [String.t()]
  def input_lines(t) do
    bad =
      case t.log_bad_lines do
        0 ->
          []

        n ->
          shown = Enum.take(t.bad_lines, 10)
          more = if n > length(shown), do: "; #{n - length(shown)} more", else: ""

          [
            "#{n} bad line(s) of #{t.log_lines}: " <>
              Enum.map_join(shown, "; ", &"line #{&1.line}: #{&1.why}") <> more
          ]
      end

    cut =
      if t.log_unterminated_line,
        do: ["last line (#{t.log_unterminated_line}) has no newline: not read"],
        else: []

    unknown =
      if t.unknown_receivers == %{},
        do: [],
        else: [
          "readings of receivers not in the devices file, not replayed: " <>
            Enum.map_join(Enum.sort(t.unknown_receivers), ", ", fn {rx, n} -> "#{rx} (#{n})" end)
        ]

    bad ++ cut ++ unknown
  end

  defp pct(nil), do: "-"
  defp pct(x), do: "#{Float.round(x * 100, 1)} %"
  defp round2(nil), do: "-"
  defp round2(x), do: Float.round(x * 1.0, 2)
end
