defmodule TartarusTools.SVG do
  @moduledoc """
  Small plain-SVG charts for experiment reports: line charts, bar charts, box plots, Gantt
  charts and plans (shapes in metres or plot units: a topology, a walk over it, an arena,
  with a scale bar), with no dependency beyond Elixir.

  Every chart function takes data and a keyword list of options and returns a standalone SVG
  document as a binary: valid XML (all text is escaped), with a `<title>`, readable in any
  browser. `write!/2` saves it.

      iex> svg = TartarusTools.SVG.line_chart(
      ...>   [%{name: "population", points: [{0, 10}, {1, 14}, {2, 13}]}],
      ...>   title: "Antibodies", x_label: "step", y_label: "count"
      ...> )
      iex> String.starts_with?(svg, "<?xml") and svg =~ "<title>Antibodies</title>"
      true

  ## Common options

    * `:title` - chart title, shown on top and as the document `<title>` (default `"chart"`);
    * `:subtitle` - a smaller line under the title: the parameters and seed of the run;
    * `:note` - a footnote at the bottom left (what the error bars or boxes mean);
    * `:x_label`, `:y_label` - axis labels; `:x_unit`, `:y_unit` - appended as `"label (unit)"`;
    * `:x_integer`, `:y_integer` - integer ticks only (`true`), never (`false`) or when every
      value on that axis is an integer (`:auto`, the default): no "robot 1.5" or "lap 2.5";
    * `:width`, `:height` - pixels (defaults 720 x 420; a Gantt chart grows with its rows).

  Axes get "nice" ticks (1, 2 or 5 times a power of ten, see `nice_ticks/3`). Charts never
  crash on edge cases: an empty data set draws empty axes with a "no data" note, a single
  point draws a marker, equal values get a small range around them. Malformed data (a point
  that is not `{number, number}`, a span that ends before it starts) raises `ArgumentError`
  naming the chart, what was expected and what arrived.

  Labels and names may be strings, atoms or numbers; anything else is shown with `inspect/1`.
  """

  @palette ~w(#4e79a7 #f28e2b #e15759 #76b7b2 #59a14f #edc948 #b07aa1 #ff9da7 #9c755f #bab0ac)

  @typedoc """
  One line of a line chart; `:intervals` (optional) are error bars `{x, lo, hi}`, as
  `mean_series/2` builds them.
  """
  @type series :: %{
          required(:name) => term,
          required(:points) => [{number, number}],
          optional(:intervals) => [{number, number, number}]
        }

  @typedoc "A reference drawn over a line chart: a dashed line or points (`style: :points`)."
  @type ref_series :: %{
          required(:name) => term,
          required(:points) => [{number, number}],
          optional(:style) => :line | :points
        }

  @typedoc "One bar: a map with `:label` and `:value` (and optional `:color`), or `{label, value}`."
  @type bar :: %{label: term, value: number} | {term, number}

  @typedoc "What `mean_series/2` returns: a series with error bars and its sample counts."
  @type mean_series :: %{
          name: term,
          points: [{number, float}],
          intervals: [{number, float, float}],
          n: [{number, non_neg_integer}]
        }

  @typedoc "One box of a box plot: `%{name: term, samples: [number]}` or `{name, samples}`."
  @type group :: %{name: term, samples: [number]} | {term, [number]}

  @typedoc "One span of a Gantt row; `:label` and `:group` are optional."
  @type span :: %{start: number, stop: number, label: term, group: term}

  @typedoc "One Gantt row."
  @type row :: %{label: term, spans: [span]}

  ## Public helpers

  @doc """
  "Nice" tick values covering `[min, max]`: about `target` ticks at 1, 2 or 5 times a power
  of ten. Integers when the step is whole. Equal bounds are widened.

  ## Examples

      iex> TartarusTools.SVG.nice_ticks(0, 97)
      [0, 20, 40, 60, 80, 100]
      iex> TartarusTools.SVG.nice_ticks(0.12, 0.31, 4)
      [0.1, 0.15, 0.2, 0.25, 0.3, 0.35]
      iex> TartarusTools.SVG.nice_ticks(5, 5)
      [4.4, 4.6, 4.8, 5.0, 5.2, 5.4, 5.6]
  """
  @spec nice_ticks(number, number, pos_integer) :: [number]
  def nice_ticks(min, max, target \\ 5) when is_number(min) and is_number(max) and target > 0 do
    {lo, hi} = if min <= max, do: {min, max}, else: {max, min}

    {lo, hi} =
      cond do
        lo != hi -> {lo, hi}
        lo == 0 -> {-1, 1}
        true -> {lo - abs(lo) * 0.1, hi + abs(hi) * 0.1}
      end

    raw = (hi - lo) / target
    mag = :math.pow(10, Float.floor(:math.log10(raw)))

    nice =
      case raw / mag do
        r when r < 1.5 -> 1
        r when r < 3 -> 2
        r when r < 7 -> 5
        _ -> 10
      end

    step = nice * mag
    first = Float.floor(lo / step + 1.0e-9)
    last = Float.ceil(hi / step - 1.0e-9)
    decimals = max(0, -trunc(Float.floor(:math.log10(step) + 1.0e-9)))

    for k <- trunc(first)..trunc(last) do
      value = k * step

      if decimals == 0 and step >= 1,
        do: round(value),
        else: Float.round(value * 1.0, decimals)
    end
  end

  @doc """
  Writes an SVG document to `path`, creating parent directories. Returns `path`.
  """
  @spec write!(Path.t(), iodata) :: Path.t()
  def write!(path, svg) do
    File.mkdir_p!(Path.dirname(path))
    File.write!(path, svg)
    path
  end

  @doc """
  A line-chart series of means over trials with their 95 % confidence intervals, from
  `[{x, samples}]`: the mean and interval of each `x` are `TartarusTools.Stats.mean_ci/1`'s
  (Student's t). An `x` with no samples is left out; one with a single sample gets a point
  and no error bar. Pass the result to `line_chart/2` with a `:note` saying what the bars
  are (`ci_note/1` writes one).

      iex> s = TartarusTools.SVG.mean_series("path 1", [{1, [10, 12, 14]}, {2, [9]}, {3, []}])
      iex> {s.points, s.n, length(s.intervals)}
      {[{1, 12.0}, {2, 9.0}], [{1, 3}, {2, 1}], 1}
  """
  @spec mean_series(term, [{number, [number]}]) :: mean_series
  def mean_series(name, samples_by_x) when is_list(samples_by_x) do
    cis = for {x, xs} <- samples_by_x, ci = TartarusTools.Stats.mean_ci(xs), do: {x, ci}

    %{
      name: name,
      points: Enum.map(cis, fn {x, ci} -> {x, ci.mean * 1.0} end),
      intervals: for({x, %{lo: lo, hi: hi}} <- cis, lo != nil, do: {x, lo, hi}),
      n: Enum.map(cis, fn {x, ci} -> {x, ci.n} end)
    }
  end

  @doc """
  The footnote of a chart of means: what its error bars are and over how many samples.

      iex> TartarusTools.SVG.ci_note([3, 3, 2], "trials")
      "points: mean over 2-3 trials; error bars: 95 % confidence interval of the mean (Student's t)"
      iex> TartarusTools.SVG.ci_note([5], "trials", "bars")
      "bars: mean over 5 trials; error bars: 95 % confidence interval of the mean (Student's t)"
  """
  @spec ci_note([non_neg_integer], String.t(), String.t()) :: String.t()
  def ci_note(ns, what, mark \\ "points") do
    {lo, hi} = Enum.min_max(ns, fn -> {0, 0} end)
    count = if lo == hi, do: "#{lo}", else: "#{lo}-#{hi}"

    "#{mark}: mean over #{count} #{what}; " <>
      "error bars: 95 % confidence interval of the mean (Student's t)"
  end

  ## Line chart

  @doc """
  A line chart of one or more series `%{name: term, points: [{x, y}]}`, drawn in the given
  order with a legend. Extra options: `:x_min`, `:x_max`, `:y_min`, `:y_max` (force the
  range to include these), `:markers` (draw points; default when a series has at most 60),
  `:lines` (default true; `false` draws points only: a scatter plot, one colour per series),
  `:references` (`t:ref_series/0`s drawn in black over the data, dashed or as crosses, with
  their names in the legend: an ideal line, the thesis's numbers labelled "thesis").
  A series with `:intervals` gets error bars (see `mean_series/2`).

  ## Examples

      iex> svg = TartarusTools.SVG.line_chart([%{name: "a<b", points: [{1, 1}]}], title: "one point")
      iex> svg =~ "a&lt;b"
      true
  """
  @spec line_chart([series], keyword) :: binary
  def line_chart(series, opts \\ []) when is_list(series) do
    series = Enum.map(series, &check_series!/1)
    refs = opts |> Keyword.get(:references, []) |> Enum.map(&check_series!/1)
    points = Enum.flat_map(series, & &1.points)
    names = Enum.map(series, & &1.name)
    layout = layout(opts, legend: names ++ Enum.map(refs, & &1.name))

    {xs, ys} = Enum.unzip(points ++ Enum.flat_map(refs, & &1.points))
    bars = for s <- series, {_, lo, hi} <- s.intervals, v <- [lo, hi], do: v
    x_ticks = ticks(xs ++ bounds(opts, :x_min, :x_max), opts, :x_integer)
    y_ticks = ticks(ys ++ bars ++ bounds(opts, :y_min, :y_max), opts, :y_integer)
    sx = scale(x_ticks, layout.left, layout.left + layout.plot_w)
    sy = scale(y_ticks, layout.top + layout.plot_h, layout.top)

    lines =
      series
      |> Enum.with_index()
      |> Enum.map(fn {%{name: name, points: pts} = s, i} ->
        color = color(i)
        coords = Enum.map(pts, fn {x, y} -> [num(sx.(x)), ",", num(sy.(y)), " "] end)
        lines? = Keyword.get(opts, :lines, true)

        markers? =
          Keyword.get(opts, :markers, length(pts) <= 60) or length(pts) == 1 or not lines?

        circles =
          if markers?,
            do:
              Enum.map(pts, fn {x, y} ->
                [
                  ~s(<circle cx="#{num(sx.(x))}" cy="#{num(sy.(y))}" r="2.5" fill="#{color}">),
                  "<title>",
                  esc(name),
                  ": (",
                  fmt(x),
                  ", ",
                  fmt(y),
                  ")</title></circle>\n"
                ]
              end),
            else: []

        polyline =
          if lines? and length(pts) > 1,
            do: [
              ~s(<polyline fill="none" stroke="#{color}" stroke-width="2" points="),
              coords,
              ~s("><title>),
              esc(name),
              "</title></polyline>\n"
            ],
            else: []

        errors =
          Enum.map(s.intervals, fn {x, lo, hi} ->
            [cx, ylo, yhi] = [sx.(x), sy.(lo), sy.(hi)]

            [
              ~s(<g class="interval" data-x="#{fmt(x)}" data-lo="#{fmt(lo)}" data-hi="#{fmt(hi)}">),
              "<title>",
              esc(name),
              ": ",
              fmt(x),
              " → ",
              fmt(lo),
              "–",
              fmt(hi),
              "</title>\n",
              line(cx, ylo, cx, yhi, color, 1.5),
              line(cx - 4, ylo, cx + 4, ylo, color, 1.5),
              line(cx - 4, yhi, cx + 4, yhi, color, 1.5),
              "</g>\n"
            ]
          end)

        [~s(<g class="series">\n), polyline, errors, circles, "</g>\n"]
      end)

    references =
      Enum.map(refs, fn %{name: name, points: pts} = r ->
        if Map.get(r, :style, :line) == :points do
          Enum.map(pts, fn {x, y} ->
            [cx, cy] = [sx.(x), sy.(y)]

            [
              ~s(<g class="reference" data-x="#{fmt(x)}" data-y="#{fmt(y)}"><title>),
              esc(name),
              ": (",
              fmt(x),
              ", ",
              fmt(y),
              ")</title>\n",
              line(cx - 5, cy - 5, cx + 5, cy + 5, "#000", 2),
              line(cx - 5, cy + 5, cx + 5, cy - 5, "#000", 2),
              "</g>\n"
            ]
          end)
        else
          coords = Enum.map(pts, fn {x, y} -> [num(sx.(x)), ",", num(sy.(y)), " "] end)

          [
            ~s(<polyline class="reference" fill="none" stroke="#000" stroke-width="1.5" ),
            ~s(stroke-dasharray="6 4" points="),
            coords,
            ~s("><title>),
            esc(name),
            "</title></polyline>\n"
          ]
        end
      end)

    ref_legend =
      Enum.map(refs, fn r ->
        {r.name, "#000", if(Map.get(r, :style, :line) == :points, do: :cross, else: :dash)}
      end)

    body = [
      axes(layout, x_ticks, y_ticks, sx, sy, opts),
      lines,
      references,
      if(points == [], do: no_data(layout), else: []),
      legend(layout, Enum.with_index(names, fn name, i -> {name, color(i), :line} end) ++ ref_legend)
    ]

    document(layout, opts, body)
  end

  defp check_series!(%{name: name, points: points} = s) when is_list(points) do
    Enum.each(points, fn
      {x, y} when is_number(x) and is_number(y) ->
        :ok

      other ->
        raise ArgumentError,
              "SVG.line_chart/2: expected points {x, y} of numbers in series #{inspect(name)}, " <>
                "got: #{inspect(other)}"
    end)

    intervals = Map.get(s, :intervals, [])

    Enum.each(intervals, fn
      {x, lo, hi} when is_number(x) and is_number(lo) and is_number(hi) and lo <= hi ->
        :ok

      other ->
        raise ArgumentError,
              "SVG.line_chart/2: expected intervals {x, lo, hi} with lo <= hi in series " <>
                "#{inspect(name)}, got: #{inspect(other)}"
    end)

    s |> Map.take([:style]) |> Map.merge(%{name: name, points: points, intervals: intervals})
  end

  defp check_series!(other) do
    raise ArgumentError,
          "SVG.line_chart/2: expected series %{name: term, points: [{x, y}]}, got: #{inspect(other)}"
  end

  ## Bar chart

  @doc """
  A bar chart, one bar per entry, in the given order. Bars may carry their own `:color`;
  values are printed above the bars. Negative values hang below the zero line. A bar with
  `:lo` and `:hi` gets an error bar (say what it is in `:note`; `TartarusTools.Stats.mean_ci/1`
  gives a 95 % interval of a mean).

  ## Examples

      iex> svg = TartarusTools.SVG.bar_chart([{"ours", 12}, {"thesis", 15}], title: "Hops")
      iex> svg =~ "thesis"
      true
  """
  @spec bar_chart([bar], keyword) :: binary
  def bar_chart(bars, opts \\ []) when is_list(bars) do
    bars = Enum.map(bars, &check_bar!/1)
    layout = layout(opts, [])
    values = Enum.flat_map(bars, &[&1.value | for(k <- [:lo, :hi], v = &1[k], do: v)])
    y_ticks = ticks([0 | values] ++ bounds(opts, :y_min, :y_max), opts, :y_integer)
    sy = scale(y_ticks, layout.top + layout.plot_h, layout.top)
    n = length(bars)
    band = if n > 0, do: layout.plot_w / n, else: layout.plot_w
    rotate? = n > 12

    rects =
      bars
      |> Enum.with_index()
      |> Enum.map(fn {%{label: label, value: value} = bar, i} ->
        x = layout.left + i * band + band * 0.15
        w = band * 0.7
        {y0, y1} = {sy.(max(value, 0)), sy.(min(value, 0))}
        cx = x + w / 2
        label_y = layout.top + layout.plot_h + 16

        {error, top} =
          case bar do
            %{lo: lo, hi: hi} when is_number(lo) and is_number(hi) ->
              {[
                 ~s(<g class="interval" data-lo="#{fmt(lo)}" data-hi="#{fmt(hi)}"><title>),
                 esc(label),
                 ": ",
                 fmt(lo),
                 "–",
                 fmt(hi),
                 "</title>\n",
                 line(cx, sy.(lo), cx, sy.(hi), "#222", 1.5),
                 line(cx - 5, sy.(lo), cx + 5, sy.(lo), "#222", 1.5),
                 line(cx - 5, sy.(hi), cx + 5, sy.(hi), "#222", 1.5),
                 "</g>\n"
               ], min(y0, sy.(hi))}

            _ ->
              {[], y0}
          end

        [
          ~s(<rect x="#{num(x)}" y="#{num(y0)}" width="#{num(w)}" height="#{num(max(y1 - y0, 0.5))}" ),
          ~s(fill="#{Map.get(bar, :color) || color(0)}"><title>),
          esc(label),
          ": ",
          fmt(value),
          "</title></rect>\n",
          error,
          ~s(<text x="#{num(if error == [], do: cx, else: cx + 8)}" ),
          ~s(y="#{num(if value < 0, do: y1 + 13, else: top - 4)}" ),
          ~s(text-anchor="#{if error == [], do: "middle", else: "start"}" font-size="11">),
          fmt(value),
          "</text>\n",
          if rotate? do
            ~s(<text x="#{num(cx)}" y="#{num(label_y)}" text-anchor="end" ) <>
              ~s[transform="rotate(-45 #{num(cx)} #{num(label_y)})">]
          else
            ~s(<text x="#{num(cx)}" y="#{num(label_y)}" text-anchor="middle">)
          end,
          esc(label),
          "</text>\n"
        ]
      end)

    body = [
      y_axis(layout, y_ticks, sy, opts),
      x_baseline(layout, sy.(0)),
      x_title(layout, opts),
      rects,
      if(bars == [], do: no_data(layout), else: [])
    ]

    document(layout, opts, body)
  end

  defp check_bar!({label, value}), do: check_bar!(%{label: label, value: value})
  defp check_bar!(%{label: _, value: v} = bar) when is_number(v) do
    case bar do
      %{lo: lo, hi: hi} when is_number(lo) and is_number(hi) and lo > hi ->
        raise ArgumentError,
              "SVG.bar_chart/2: expected lo <= hi in bar #{inspect(bar.label)}, got: #{inspect(bar)}"

      _ ->
        bar
    end
  end

  defp check_bar!(other) do
    raise ArgumentError,
          "SVG.bar_chart/2: expected bars %{label: term, value: number} or {label, value}, " <>
            "got: #{inspect(other)}"
  end

  ## Box plot

  @doc """
  A box plot: one box per group of samples (median, quartiles, whiskers at 1.5 IQR, outliers
  as open circles; see `TartarusTools.Stats.box/1`). Each group is labelled with its name and
  sample count.

  The median line is the conventional median (`TartarusTools.Stats.median_mid/1`: of an
  even count the mean of the two middle samples, so [11, 13] is drawn at 12), the
  `median_mid` of a sweep's aggregates; the quartiles are nearest rank, actual samples
  (`Stats.box/2`). A group of at most `:points_max` samples (default 20) also shows every
  sample as a dot beside its box, so a reader sees the data the box summarises. A footnote
  says all this, naming open circles and dots only when some are drawn (`:note` replaces
  it).

  ## Examples

      iex> svg = TartarusTools.SVG.box_plot([{"ring", [1, 2, 3, 10]}, %{name: "grid", samples: []}])
      iex> svg =~ "n=4" and svg =~ "n=0"
      true
  """
  @spec box_plot([group], keyword) :: binary
  def box_plot(groups, opts \\ []) when is_list(groups) do
    groups =
      Enum.map(groups, fn
        {name, samples} when is_list(samples) ->
          {name, TartarusTools.Stats.box(samples, median: :mid), samples}

        %{name: name, samples: samples} when is_list(samples) ->
          {name, TartarusTools.Stats.box(samples, median: :mid), samples}

        other ->
          raise ArgumentError,
                "SVG.box_plot/2: expected groups %{name: term, samples: [number]} or {name, samples}, got: #{inspect(other)}"
      end)

    layout = layout(opts, [])
    all = for {_, %{} = s, _} <- groups, v <- [s.whisker_low, s.whisker_high | s.outliers], do: v
    y_ticks = ticks(all ++ bounds(opts, :y_min, :y_max), opts, :y_integer)
    points_max = Keyword.get(opts, :points_max, 20)

    opts = Keyword.put_new_lazy(opts, :note, fn -> box_note(groups, points_max) end)
    sy = scale(y_ticks, layout.top + layout.plot_h, layout.top)
    n = length(groups)
    band = if n > 0, do: layout.plot_w / n, else: layout.plot_w

    boxes =
      groups
      |> Enum.with_index()
      |> Enum.map(fn {{name, stats, samples}, i} ->
        x = layout.left + i * band + band * 0.2
        w = band * 0.6
        cx = x + w / 2
        label_y = layout.top + layout.plot_h + 16

        label = [
          ~s(<text x="#{num(cx)}" y="#{num(label_y)}" text-anchor="middle">),
          esc(name),
          "</text>\n",
          ~s(<text x="#{num(cx)}" y="#{num(label_y + 14)}" text-anchor="middle" font-size="10" fill="#555">n=),
          Integer.to_string(if(stats, do: stats.n, else: 0)),
          "</text>\n"
        ]

        dots =
          if stats != nil and stats.n <= points_max do
            samples
            |> Enum.sort()
            |> Enum.with_index()
            |> Enum.map(fn {v, k} ->
              dx = x + w + 6 + rem(k, 3) * 4

              [
                ~s(<circle class="sample" cx="#{num(dx)}" cy="#{num(sy.(v))}" r="2" ),
                ~s(fill="#{color(i)}" data-value="#{fmt(v)}"><title>),
                fmt(v),
                "</title></circle>\n"
              ]
            end)
          else
            []
          end

        [label, if(stats, do: box(stats, name, x, w, cx, sy, color(i)), else: []), dots]
      end)

    body = [
      y_axis(layout, y_ticks, sy, opts),
      x_title(layout, opts),
      boxes,
      if(all == [], do: no_data(layout), else: [])
    ]

    document(layout, opts, body)
  end

  # The footnote says what is drawn: open circles only when some group has samples beyond
  # its whiskers, dots only when some group is small enough to show its samples.
  defp box_note(groups, points_max) do
    stats = for {_, %{} = s, _} <- groups, do: s
    outliers? = Enum.any?(stats, &(&1.outliers != []))
    {dotted, undotted} = Enum.split_with(stats, &(&1.n <= points_max))

    dots =
      cond do
        dotted == [] -> ""
        undotted == [] -> "; dots beside a box: each of its samples"
        true -> "; dots beside a box of at most #{points_max} samples: each of them"
      end

    "box: median (of an even n, the mean of the two middle samples), nearest-rank " <>
      "quartiles; whiskers to the farthest samples within 1.5 IQR" <>
      if(outliers?, do: "; open circles: samples beyond the whiskers", else: "") <> dots
  end

  defp box(s, name, x, w, cx, sy, color) do
    tip = [
      esc(name),
      ": median ",
      fmt(s.median),
      ", Q1 ",
      fmt(s.q1),
      ", Q3 ",
      fmt(s.q3),
      ", n=",
      Integer.to_string(s.n)
    ]

    {q1, q3} = {sy.(s.q1), sy.(s.q3)}
    cap = w / 4

    [
      line(cx, sy.(s.whisker_low), cx, q1, "#333"),
      line(cx, q3, cx, sy.(s.whisker_high), "#333"),
      line(cx - cap, sy.(s.whisker_low), cx + cap, sy.(s.whisker_low), "#333"),
      line(cx - cap, sy.(s.whisker_high), cx + cap, sy.(s.whisker_high), "#333"),
      ~s(<rect x="#{num(x)}" y="#{num(q3)}" width="#{num(w)}" height="#{num(max(q1 - q3, 0.5))}" ),
      ~s(fill="#{color}" fill-opacity="0.6" stroke="#333"><title>),
      tip,
      "</title></rect>\n",
      ~s(<g class="median" data-value="#{fmt(s.median)}">),
      line(x, sy.(s.median), x + w, sy.(s.median), "#000", 2),
      "</g>\n",
      Enum.map(s.outliers, fn o ->
        [
          ~s(<circle class="outlier" cx="#{num(cx)}" cy="#{num(sy.(o))}" r="3" fill="none" stroke="#{color}">),
          "<title>",
          fmt(o),
          "</title></circle>\n"
        ]
      end)
    ]
  end

  ## Plan (a map in world units)

  @typedoc """
  One shape of `plan/2`, in world units (metres, or plot units): a map with `:shape` and

    * `:circle` - `:x`, `:y`, and `:r` (world) or `:r_px` (pixels);
    * `:rect` - `:x`, `:y` (its lower-left corner when y grows upwards), `:w`, `:h`;
    * `:line` - `:points` `[{x, y}]` (two or more), `:width` (world) or `:width_px`,
      optional `:dash` (`true`) and `:arrow` (`true`: an arrowhead at the last point);
    * `:text` - `:x`, `:y`, `:text` (optional `:size`, `:anchor`);
    * `:marker` - `:x`, `:y`, `:kind`: `:start` (a disc) or `:end` (a smaller square, so
      that both show where a closed path ends where it began), at a fixed size whatever
      the scale.

  Any shape may have `:fill`, `:stroke`, `:opacity`, `:label` (a text beside it, at a
  fixed size, above right, or below right with `label_below: true`), `:title` (a tooltip), `:class` and `:data` (`%{name => value}`, written as
  `data-name` attributes, so that a test can read the drawing back).
  """
  @type shape :: %{
          required(:shape) => :circle | :rect | :line | :text | :marker,
          optional(atom) => term
        }

  @doc """
  A plan: shapes placed in world coordinates (a topology's node positions, an arena in
  metres) with one scale for both axes, the common title, subtitle and note, an optional
  legend and, when `:unit` is given, a scale bar in that unit (`<g class="scale-bar"
  data-length="0.5" data-px="100.00">`: so many units are so many pixels).

  Options besides the common ones: `:bounds` `{x0, y0, x1, y1}` (default: the shapes'
  extent, padded), `:unit` (e.g. `"m"`), `:y_up` (default `true`: world y grows upwards),
  `:legend` `[{name, colour, kind}]` with `kind` one of `:line`, `:dash`, `:box`, `:dot`,
  `:start`, `:end`, and `:max_height` (pixels of the plan, default 440); the height follows
  the plan's aspect ratio. Circles and markers carry their world position as
  `data-x`/`data-y`; the group of shapes carries the scale (`data-px-per-unit`).

      iex> svg = TartarusTools.SVG.plan(
      ...>   [%{shape: :circle, x: 0, y: 0, r: 0.1, label: "light"},
      ...>    %{shape: :marker, kind: :start, x: 1, y: 1}],
      ...>   title: "arena", unit: "m")
      iex> svg =~ "light" and svg =~ ~s(class="scale-bar")
      true
  """
  @spec plan([shape], keyword) :: binary
  def plan(shapes, opts \\ []) when is_list(shapes) do
    Enum.each(shapes, &check_shape!/1)
    legend = Keyword.get(opts, :legend, [])
    {x0, y0, x1, y1} = Keyword.get_lazy(opts, :bounds, fn -> extent(shapes) end)
    {dx, dy} = {max(x1 - x0, 1.0e-9), max(y1 - y0, 1.0e-9)}
    width = Keyword.get(opts, :width, 720)

    legend_w =
      if legend == [],
        do: 0,
        else: min(220, 46 + (legend |> Enum.map(&text_width(elem(&1, 0))) |> Enum.max()))

    {left, top, bottom} = {20, 50, 48}
    plot_w = max(width - left - 20 - legend_w, 10)
    k = min(plot_w / dx, Keyword.get(opts, :max_height, 440) / dy)
    plot_h = dy * k
    left = left + (plot_w - dx * k) / 2
    y_up = Keyword.get(opts, :y_up, true)

    t = %{
      x: fn x -> left + (x - x0) * k end,
      y: fn y -> if y_up, do: top + (y1 - y) * k, else: top + (y - y0) * k end,
      k: k
    }

    layout = %{
      width: width,
      height: round(top + plot_h + bottom),
      left: left,
      top: top,
      plot_w: dx * k,
      plot_h: plot_h
    }

    body = [
      ~s(<g class="plan" data-px-per-unit="#{num(k)}">\n),
      Enum.map(shapes, &draw_shape(&1, t)),
      "</g>\n",
      scale_bar(Keyword.get(opts, :unit), dx, k, left, top + plot_h + 20),
      plan_legend(legend, width - legend_w, top)
    ]

    document(layout, opts, body)
  end

  defp check_shape!(%{shape: :circle, x: x, y: y} = s) when is_number(x) and is_number(y) do
    if is_number(s[:r]) or is_number(s[:r_px]), do: :ok, else: bad_shape!(s)
  end

  defp check_shape!(%{shape: :rect, x: x, y: y, w: w, h: h})
       when is_number(x) and is_number(y) and is_number(w) and is_number(h),
       do: :ok

  defp check_shape!(%{shape: :line, points: [_, _ | _] = pts} = s) do
    if Enum.all?(pts, &match?({x, y} when is_number(x) and is_number(y), &1)),
      do: :ok,
      else: bad_shape!(s)
  end

  defp check_shape!(%{shape: :text, x: x, y: y, text: _}) when is_number(x) and is_number(y),
    do: :ok

  defp check_shape!(%{shape: :marker, x: x, y: y, kind: kind})
       when is_number(x) and is_number(y) and kind in [:start, :end],
       do: :ok

  defp check_shape!(other), do: bad_shape!(other)

  defp bad_shape!(other) do
    raise ArgumentError,
          "SVG.plan/2: expected shapes %{shape: :circle | :rect | :line | :text | :marker} " <>
            "with numeric coordinates (see the shape type), got: #{inspect(other)}"
  end

  defp extent([]), do: {0, 0, 1, 1}

  defp extent(shapes) do
    pts =
      Enum.flat_map(shapes, fn
        %{shape: :line, points: pts} -> pts
        %{shape: :rect, x: x, y: y, w: w, h: h} -> [{x, y}, {x + w, y + h}]
        %{shape: :circle, x: x, y: y} = c -> [{x - (c[:r] || 0), y - (c[:r] || 0)}, {x + (c[:r] || 0), y + (c[:r] || 0)}]
        %{x: x, y: y} -> [{x, y}]
      end)

    {xs, ys} = Enum.unzip(pts)
    {a, b, c, d} = {Enum.min(xs), Enum.min(ys), Enum.max(xs), Enum.max(ys)}
    pad = max(max(c - a, d - b) * 0.08, 0.05)
    {a - pad, b - pad, c + pad, d + pad}
  end

  defp draw_shape(s, t) do
    extra = shape_attrs(s)

    element =
      case s.shape do
        :circle ->
          r = Map.get_lazy(s, :r_px, fn -> s.r * t.k end)

          el(
            "circle",
            ~s(cx="#{num(t.x.(s.x))}" cy="#{num(t.y.(s.y))}" r="#{num(max(r, 0.5))}" ) <>
              ~s(data-x="#{fmt(s.x)}" data-y="#{fmt(s.y)}" fill="#{Map.get(s, :fill, "#4e79a7")}" ) <>
              ~s(stroke="#{Map.get(s, :stroke, "none")}"#{extra}),
            s[:title]
          )

        :rect ->
          {ya, yb} = {t.y.(s.y), t.y.(s.y + s.h)}

          el(
            "rect",
            ~s(x="#{num(t.x.(s.x))}" y="#{num(min(ya, yb))}" width="#{num(s.w * t.k)}" ) <>
              ~s(height="#{num(abs(yb - ya))}" fill="#{Map.get(s, :fill, "#ccc")}" ) <>
              ~s(stroke="#{Map.get(s, :stroke, "none")}"#{extra}),
            s[:title]
          )

        :line ->
          pts = Enum.map_join(s.points, " ", fn {x, y} -> "#{num(t.x.(x))},#{num(t.y.(y))}" end)
          w = max(Map.get_lazy(s, :width_px, fn -> Map.get(s, :width, 0) * t.k end), 0.5)
          colour = Map.get(s, :stroke, "#333")
          dash = if s[:dash], do: ~s( stroke-dasharray="6 4"), else: ""

          [
            el(
              "polyline",
              ~s(fill="none" stroke="#{colour}" stroke-width="#{num(w)}" ) <>
                ~s(stroke-linejoin="round" points="#{pts}"#{dash}#{extra}),
              s[:title]
            ),
            if(s[:arrow], do: arrow_head(s.points, t, colour, w), else: [])
          ]

        :text ->
          [
            ~s(<text x="#{num(t.x.(s.x))}" y="#{num(t.y.(s.y))}" font-size="#{Map.get(s, :size, 11)}" ),
            ~s(fill="#{Map.get(s, :fill, "#222")}" text-anchor="#{Map.get(s, :anchor, "start")}"#{extra}>),
            esc(s.text),
            "</text>\n"
          ]

        :marker ->
          {x, y} = {t.x.(s.x), t.y.(s.y)}
          colour = Map.get(s, :fill, if(s.kind == :start, do: "#2ca02c", else: "#d62728"))
          at = ~s(data-x="#{fmt(s.x)}" data-y="#{fmt(s.y)}" fill="#{colour}" stroke="#000" stroke-width="1.5")

          case s.kind do
            :start ->
              el("circle", ~s(class="start" cx="#{num(x)}" cy="#{num(y)}" r="8" #{at}#{extra}), s[:title])

            :end ->
              el(
                "rect",
                ~s(class="end" x="#{num(x - 4.5)}" y="#{num(y - 4.5)}" width="9" height="9" #{at}#{extra}),
                s[:title]
              )
          end
      end

    [element, shape_label(s, t)]
  end

  defp el(tag, attrs, nil), do: ["<", tag, " ", attrs, "/>\n"]
  defp el(tag, attrs, title), do: ["<", tag, " ", attrs, "><title>", esc(title), "</title></", tag, ">\n"]

  defp shape_attrs(s) do
    class = if s[:class] && s.shape != :marker, do: ~s( class="#{esc(s.class)}"), else: ""
    opacity = if s[:opacity], do: ~s( opacity="#{num(s.opacity)}"), else: ""

    data =
      Enum.map_join(Map.get(s, :data, %{}), fn {k, v} ->
        ~s( data-#{k}="#{IO.iodata_to_binary(esc(if is_float(v), do: fmt(v), else: v))}")
      end)

    class <> opacity <> data
  end

  defp shape_label(%{label: label} = s, t) when label != nil do
    {x, y} =
      case s do
        %{shape: :line, points: pts} -> List.last(pts)
        %{shape: :rect, x: x, y: y, w: w, h: h} -> {x + w, y + h}
        %{x: x, y: y} -> {x, y}
      end

    off =
      case s do
        %{shape: :circle} -> Map.get_lazy(s, :r_px, fn -> s.r * t.k end) + 3
        %{shape: :marker} -> 9
        _ -> 3
      end

    dy = if s[:label_below], do: off + 8, else: -off

    [
      ~s(<text class="label" x="#{num(t.x.(x) + off)}" y="#{num(t.y.(y) + dy)}" font-size="11" ),
      ~s(fill="#222" stroke="#fff" stroke-width="3" paint-order="stroke">),
      esc(label),
      "</text>\n"
    ]
  end

  defp shape_label(_s, _t), do: []

  # An arrowhead at the last point of a line, pointing along its last segment.
  defp arrow_head(points, t, colour, w) do
    [{xa, ya}, {xb, yb}] = Enum.take(points, -2)
    {ax, ay, bx, by} = {t.x.(xa), t.y.(ya), t.x.(xb), t.y.(yb)}
    len = :math.sqrt((bx - ax) * (bx - ax) + (by - ay) * (by - ay))

    if len < 1.0e-6 do
      []
    else
      {ux, uy} = {(bx - ax) / len, (by - ay) / len}
      size = 5 + 2 * w
      {px, py} = {bx - ux * size, by - uy * size}
      {nx, ny} = {-uy * size * 0.5, ux * size * 0.5}

      ~s(<polygon points="#{num(bx)},#{num(by)} #{num(px + nx)},#{num(py + ny)} #{num(px - nx)},#{num(py - ny)}" fill="#{colour}"/>\n)
    end
  end

  # A scale bar: the longest 1, 2 or 5 times a power of ten that fits a quarter of the plan.
  defp scale_bar(nil, _dx, _k, _x, _y), do: []

  defp scale_bar(unit, dx, k, x, y) do
    target = dx / 4
    p = :math.pow(10, Float.floor(:math.log10(target)))
    len = Enum.find([5 * p, 2 * p, p], &(&1 <= target)) || p
    len = if len == Float.round(len), do: round(len), else: Float.round(len, 6)
    w = len * k

    [
      ~s(<g class="scale-bar" data-length="#{fmt(len)}" data-unit="#{esc(unit)}" data-px="#{num(w)}">\n),
      line(x, y, x + w, y, "#000", 3),
      line(x, y - 5, x, y + 5, "#000", 1.5),
      line(x + w, y - 5, x + w, y + 5, "#000", 1.5),
      ~s(<text x="#{num(x + w + 6)}" y="#{num(y + 4)}">),
      fmt(len),
      " ",
      esc(unit),
      "</text>\n</g>\n"
    ]
  end

  defp plan_legend([], _x, _y), do: []

  defp plan_legend(entries, x, y0) do
    entries
    |> Enum.with_index()
    |> Enum.map(fn {{name, colour, kind}, i} ->
      y = y0 + 10 + i * 18

      swatch =
        case kind do
          :line -> line(x, y, x + 18, y, colour, 3)
          :dash -> ~s(<line x1="#{num(x)}" y1="#{num(y)}" x2="#{num(x + 18)}" y2="#{num(y)}" stroke="#{colour}" stroke-width="1.5" stroke-dasharray="6 4"/>\n)
          :box -> ~s(<rect x="#{num(x + 2)}" y="#{num(y - 6)}" width="14" height="12" fill="#{colour}" stroke="#333"/>\n)
          :dot -> ~s(<circle cx="#{num(x + 9)}" cy="#{num(y)}" r="5" fill="#{colour}" stroke="#333"/>\n)
          :start -> ~s(<circle cx="#{num(x + 9)}" cy="#{num(y)}" r="7" fill="#{colour}" stroke="#000" stroke-width="1.5"/>\n)
          :end -> ~s(<rect x="#{num(x + 3.5)}" y="#{num(y - 5.5)}" width="11" height="11" fill="#{colour}" stroke="#000" stroke-width="1.5"/>\n)
        end

      [swatch, ~s(<text x="#{num(x + 24)}" y="#{num(y + 4)}">), esc(name), "</text>\n"]
    end)
    |> then(&[~s(<g class="legend">\n), &1, "</g>\n"])
  end

  ## Gantt chart

  @doc """
  A Gantt chart: one lane per row, one bar per span from `start` to `stop`, coloured by
  `:group` with a legend of groups (spans without a group are grey). Span labels are drawn
  inside bars wide enough to hold them and always shown as tooltips. The height grows with
  the number of rows unless `:height` is given.

  ## Examples

      iex> rows = [%{label: "robot 1", spans: [%{start: 0, stop: 4, label: "t1", group: :pick}]}]
      iex> svg = TartarusTools.SVG.gantt(rows, title: "Tasks", x_label: "step")
      iex> svg =~ "robot 1" and svg =~ "pick"
      true
  """
  @spec gantt([row], keyword) :: binary
  def gantt(rows, opts \\ []) when is_list(rows) do
    rows = Enum.map(rows, &check_row!/1)
    spans = Enum.flat_map(rows, & &1.spans)
    groups = spans |> Enum.map(&Map.get(&1, :group)) |> Enum.reject(&is_nil/1) |> Enum.uniq()
    group_color = groups |> Enum.with_index() |> Map.new(fn {g, i} -> {g, color(i)} end)

    label_w = rows |> Enum.map(&text_width(&1.label)) |> Enum.max(fn -> 0 end)
    lane = 26
    height = Keyword.get(opts, :height, 45 + 60 + max(length(rows), 1) * lane)

    layout =
      layout(Keyword.put(opts, :height, height),
        legend: groups,
        left: min(max(70, label_w + 16), 240)
      )

    lane_h = layout.plot_h / max(length(rows), 1)
    x_ticks =
      ticks(Enum.flat_map(spans, &[&1.start, &1.stop]) ++ bounds(opts, :x_min, :x_max), opts, :x_integer)
    sx = scale(x_ticks, layout.left, layout.left + layout.plot_w)

    lanes =
      rows
      |> Enum.with_index()
      |> Enum.map(fn {row, i} ->
        y = layout.top + i * lane_h
        mid = y + lane_h / 2

        [
          ~s(<text x="#{num(layout.left - 8)}" y="#{num(mid + 4)}" text-anchor="end">),
          esc(row.label),
          "</text>\n",
          Enum.map(row.spans, fn span ->
            x0 = sx.(span.start)
            w = max(sx.(span.stop) - x0, 1)
            group = Map.get(span, :group)
            label = Map.get(span, :label)
            fill = Map.get(group_color, group, "#999999")

            tip = [
              if(label != nil, do: [esc(label), " "], else: []),
              if(group != nil, do: ["(", esc(group), ") "], else: []),
              fmt(span.start),
              "–",
              fmt(span.stop)
            ]

            inner =
              if label != nil and text_width(label) + 6 < w,
                do: [
                  ~s(<text x="#{num(x0 + w / 2)}" y="#{num(mid + 4)}" text-anchor="middle" ),
                  ~s(font-size="11" fill="#fff">),
                  esc(label),
                  "</text>\n"
                ],
                else: []

            [
              ~s(<rect x="#{num(x0)}" y="#{num(y + lane_h * 0.15)}" width="#{num(w)}" ),
              ~s(height="#{num(lane_h * 0.7)}" fill="#{fill}"><title>),
              tip,
              "</title></rect>\n",
              inner
            ]
          end)
        ]
      end)

    body = [
      x_axis(layout, x_ticks, sx, opts),
      y_title(layout, opts),
      lanes,
      if(spans == [], do: no_data(layout), else: []),
      legend(layout, Enum.map(groups, &{&1, Map.fetch!(group_color, &1), :box}))
    ]

    document(layout, opts, body)
  end

  defp check_row!(%{label: label, spans: spans}) when is_list(spans) do
    Enum.each(spans, fn
      %{start: a, stop: b} when is_number(a) and is_number(b) and a <= b ->
        :ok

      other ->
        raise ArgumentError,
              "SVG.gantt/2: expected spans %{start: number, stop: number} with start <= stop " <>
                "in row #{inspect(label)}, got: #{inspect(other)}"
    end)

    %{label: label, spans: spans}
  end

  defp check_row!(other) do
    raise ArgumentError,
          "SVG.gantt/2: expected rows %{label: term, spans: [span]}, got: #{inspect(other)}"
  end

  ## Layout and drawing helpers

  ## Grid chart

  @doc """
  A grid of labelled cells, one row per `rows` entry and one column per `columns` entry:
  where each of a few outcomes holds across two factors (which design wins at which
  setting and size). `cells` maps `{row, column}` to `%{class: term, label: text}` (the
  label is written in the cell, e.g. a ratio); `classes` lists `{class, name}` in legend
  order, each class one colour; a cell that is missing is drawn empty and grey ("not
  run"). Options as the other charts (`:title`, `:subtitle`, `:note`, `:x_label`,
  `:y_label`, `:width`).

  ## Examples

      iex> cells = %{{"k 60", 5} => %{class: :central, label: "0.5"}}
      iex> svg = TartarusTools.SVG.grid_chart(["k 60", "k 20"], [5, 10], cells,
      ...>   classes: [central: "central faster"], title: "map")
      iex> svg =~ "central faster" and svg =~ "not run" and svg =~ "0.5"
      true
  """
  @spec grid_chart([term], [term], %{{term, term} => map()}, keyword) :: binary
  def grid_chart(rows, columns, cells, opts \\ []) when is_list(rows) and is_list(columns) do
    classes = Keyword.get(opts, :classes, [])
    class_color = classes |> Enum.with_index() |> Map.new(fn {{c, _}, i} -> {c, color(i)} end)
    legend = Enum.map(classes, &elem(&1, 1)) ++ ["not run"]
    left = 20 + Enum.max([60 | Enum.map(rows, &text_width/1)])
    lay = layout(opts, legend: legend, left: left)
    {cw, ch} = {lay.plot_w / max(length(columns), 1), lay.plot_h / max(length(rows), 1)}

    grid =
      for {r, i} <- Enum.with_index(rows), {c, j} <- Enum.with_index(columns) do
        {x, y} = {lay.left + j * cw, lay.top + i * ch}

        {fill, label} =
          case Map.get(cells, {r, c}) do
            %{class: class} = cell -> {Map.get(class_color, class, "#999999"), Map.get(cell, :label, "")}
            nil -> {"#eeeeee", ""}
          end

        [
          ~s(<rect x="#{num(x + 1)}" y="#{num(y + 1)}" width="#{num(cw - 2)}" height="#{num(ch - 2)}" fill="#{fill}"><title>),
          esc("#{plain(r)}, #{plain(c)}: #{plain(label)}"),
          "</title></rect>\n",
          ~s(<text x="#{num(x + cw / 2)}" y="#{num(y + ch / 2 + 4)}" text-anchor="middle" font-size="11">),
          esc(label),
          "</text>\n"
        ]
      end

    row_labels =
      for {r, i} <- Enum.with_index(rows) do
        [
          ~s(<text x="#{num(lay.left - 6)}" y="#{num(lay.top + i * ch + ch / 2 + 4)}" text-anchor="end">),
          esc(r),
          "</text>\n"
        ]
      end

    bottom = lay.top + lay.plot_h

    col_labels =
      for {c, j} <- Enum.with_index(columns) do
        [
          ~s(<text x="#{num(lay.left + j * cw + cw / 2)}" y="#{num(bottom + 16)}" text-anchor="middle">),
          esc(c),
          "</text>\n"
        ]
      end

    axis =
      [
        ~s(<text x="#{num(lay.left + lay.plot_w / 2)}" y="#{num(bottom + 34)}" text-anchor="middle">),
        esc(Keyword.get(opts, :x_label, "")),
        "</text>\n",
        ~s(<text x="12" y="#{num(lay.top - 8)}">),
        esc(Keyword.get(opts, :y_label, "")),
        "</text>\n"
      ]

    lx = lay.left + lay.plot_w + 30

    legend_svg =
      for {name, i} <- Enum.with_index(legend) do
        fill = if name == "not run", do: "#eeeeee", else: color(i)
        y = lay.top + 10 + i * 20

        [
          ~s(<rect x="#{num(lx)}" y="#{num(y - 10)}" width="14" height="14" fill="#{fill}" stroke="#999"/>),
          ~s(<text x="#{num(lx + 20)}" y="#{num(y + 2)}">),
          esc(name),
          "</text>\n"
        ]
      end

    document(lay, opts, [grid, row_labels, col_labels, axis, legend_svg])
  end

  defp layout(opts, extra) do
    width = Keyword.get(opts, :width, 720)
    height = Keyword.get(opts, :height, 420)
    legend = Keyword.get(extra, :legend, [])

    legend_w =
      if legend == [],
        do: 0,
        else: min(240, 40 + (legend |> Enum.map(&text_width/1) |> Enum.max()))

    left = Keyword.get(extra, :left, 70)
    top = 45
    bottom = 60
    right = 20 + legend_w

    %{
      width: width,
      height: height,
      left: left,
      top: top,
      plot_w: max(width - left - right, 10),
      plot_h: max(height - top - bottom, 10)
    }
  end

  defp document(layout, opts, body) do
    title = Keyword.get(opts, :title, "chart")
    %{width: w, height: h} = layout

    IO.iodata_to_binary([
      ~s(<?xml version="1.0" encoding="UTF-8"?>\n),
      ~s(<svg xmlns="http://www.w3.org/2000/svg" width="#{w}" height="#{h}" viewBox="0 0 #{w} #{h}" ),
      ~s(font-family="Helvetica, Arial, sans-serif" font-size="12">\n),
      "<title>",
      esc(title),
      "</title>\n",
      ~s(<rect width="#{w}" height="#{h}" fill="#ffffff"/>\n),
      ~s(<text x="#{num(w / 2)}" y="26" text-anchor="middle" font-size="16" font-weight="bold">),
      esc(title),
      "</text>\n",
      case Keyword.get(opts, :subtitle) do
        nil ->
          []

        sub ->
          [
            ~s(<text class="subtitle" x="#{num(w / 2)}" y="40" text-anchor="middle" ),
            ~s(font-size="11" fill="#444">),
            esc(sub),
            "</text>\n"
          ]
      end,
      body,
      case Keyword.get(opts, :note) do
        nil ->
          []

        note ->
          [
            ~s(<text class="note" x="8" y="#{num(h - 6)}" font-size="10" fill="#555">),
            esc(note),
            "</text>\n"
          ]
      end,
      "</svg>\n"
    ])
  end

  defp axes(layout, x_ticks, y_ticks, sx, sy, opts) do
    [x_axis(layout, x_ticks, sx, opts), y_axis(layout, y_ticks, sy, opts)]
  end

  defp x_axis(layout, ticks, sx, opts) do
    bottom = layout.top + layout.plot_h

    [
      Enum.map(ticks, fn t ->
        x = sx.(t)

        [
          line(x, layout.top, x, bottom, "#e5e5e5"),
          ~s(<text x="#{num(x)}" y="#{num(bottom + 16)}" text-anchor="middle">#{fmt(t)}</text>\n)
        ]
      end),
      line(layout.left, bottom, layout.left + layout.plot_w, bottom, "#333"),
      x_title(layout, opts)
    ]
  end

  defp x_title(layout, opts) do
    case axis_label(opts, :x_label, :x_unit) do
      nil ->
        []

      label ->
        x = layout.left + layout.plot_w / 2
        y = layout.top + layout.plot_h + 44
        [~s(<text x="#{num(x)}" y="#{num(y)}" text-anchor="middle">), label, "</text>\n"]
    end
  end

  defp y_axis(layout, ticks, sy, opts) do
    [
      Enum.map(ticks, fn t ->
        y = sy.(t)

        [
          line(layout.left, y, layout.left + layout.plot_w, y, "#e5e5e5"),
          ~s(<text x="#{num(layout.left - 6)}" y="#{num(y + 4)}" text-anchor="end">#{fmt(t)}</text>\n)
        ]
      end),
      line(layout.left, layout.top, layout.left, layout.top + layout.plot_h, "#333"),
      y_title(layout, opts)
    ]
  end

  defp y_title(layout, opts) do
    case axis_label(opts, :y_label, :y_unit) do
      nil ->
        []

      label ->
        y = layout.top + layout.plot_h / 2

        [
          ~s[<text x="16" y="#{num(y)}" text-anchor="middle" transform="rotate(-90 16 #{num(y)})">],
          label,
          "</text>\n"
        ]
    end
  end

  defp x_baseline(layout, y), do: line(layout.left, y, layout.left + layout.plot_w, y, "#333")

  defp axis_label(opts, label_key, unit_key) do
    case {Keyword.get(opts, label_key), Keyword.get(opts, unit_key)} do
      {nil, nil} -> nil
      {label, nil} -> esc(label)
      {nil, unit} -> ["(", esc(unit), ")"]
      {label, unit} -> [esc(label), " (", esc(unit), ")"]
    end
  end

  defp legend(_layout, []), do: []

  defp legend(layout, entries) do
    x = layout.left + layout.plot_w + 16

    entries
    |> Enum.with_index()
    |> Enum.map(fn {{name, color, kind}, i} ->
      y = layout.top + 10 + i * 18

      swatch =
        case kind do
          :line ->
            line(x, y, x + 18, y, color, 3)

          :box ->
            ~s(<rect x="#{num(x)}" y="#{num(y - 6)}" width="18" height="12" fill="#{color}"/>\n)

          :dash ->
            ~s(<line x1="#{num(x)}" y1="#{num(y)}" x2="#{num(x + 18)}" y2="#{num(y)}" ) <>
              ~s(stroke="#{color}" stroke-width="1.5" stroke-dasharray="6 4"/>\n)

          :cross ->
            [line(x + 4, y - 5, x + 14, y + 5, color, 2), line(x + 4, y + 5, x + 14, y - 5, color, 2)]
        end

      [swatch, ~s(<text x="#{num(x + 24)}" y="#{num(y + 4)}">), esc(name), "</text>\n"]
    end)
    |> then(&[~s(<g class="legend">\n), &1, "</g>\n"])
  end

  defp no_data(layout) do
    x = layout.left + layout.plot_w / 2
    y = layout.top + layout.plot_h / 2
    ~s(<text x="#{num(x)}" y="#{num(y)}" text-anchor="middle" fill="#888">no data</text>\n)
  end

  defp line(x1, y1, x2, y2, color, width \\ 1) do
    ~s(<line x1="#{num(x1)}" y1="#{num(y1)}" x2="#{num(x2)}" y2="#{num(y2)}" stroke="#{color}" stroke-width="#{width}"/>\n)
  end

  defp ticks([]), do: nice_ticks(0, 1)
  defp ticks(values), do: nice_ticks(Enum.min(values), Enum.max(values))

  # Ticks of one axis; whole numbers only when the axis is integer (`opts[key]`, or `:auto`:
  # every value is an integer), widening a fractional step to 1.
  defp ticks(values, opts, key) do
    base = ticks(values)

    integer? =
      case Keyword.get(opts, key, :auto) do
        :auto -> values != [] and Enum.all?(values, &is_integer/1)
        flag -> flag == true
      end

    if integer? and not Enum.all?(base, &is_integer/1),
      do: Enum.to_list(floor(hd(base))..ceil(List.last(base))),
      else: base
  end

  defp bounds(opts, min_key, max_key) do
    for key <- [min_key, max_key], v = Keyword.get(opts, key), is_number(v), do: v
  end

  # Maps the range of `ticks` linearly onto pixels [p0, p1].
  defp scale(ticks, p0, p1) do
    {d0, d1} = {hd(ticks), List.last(ticks)}
    span = if d1 == d0, do: 1, else: d1 - d0
    fn v -> p0 + (v - d0) / span * (p1 - p0) end
  end

  defp color(i), do: Enum.at(@palette, rem(i, length(@palette)))

  defp text_width(text), do: 7 * String.length(plain(text))

  defp num(x) when is_integer(x), do: Integer.to_string(x)
  defp num(x), do: :erlang.float_to_binary(x * 1.0, decimals: 2)

  # Human-readable numbers for labels and tooltips.
  defp fmt(x) when is_integer(x), do: Integer.to_string(x)

  defp fmt(x) when is_float(x) do
    cond do
      x == Float.round(x) and abs(x) < 1.0e15 -> Integer.to_string(round(x))
      abs(x) >= 1.0e6 or abs(x) < 1.0e-3 -> :erlang.float_to_binary(x, [{:scientific, 3}])
      true -> x |> Float.round(4) |> Float.to_string()
    end
  end

  defp plain(text) when is_binary(text) do
    if String.valid?(text), do: text, else: inspect(text)
  end

  defp plain(text) when is_atom(text) or is_number(text), do: to_string(text)
  defp plain(text), do: inspect(text)

  # XML-escapes text and drops characters XML 1.0 cannot hold.
  defp esc(text) do
    text
    |> plain()
    |> String.replace(~r/[\x00-\x08\x0B\x0C\x0E-\x1F\x{FFFE}\x{FFFF}]/u, "")
    |> String.replace("&", "&amp;")
    |> String.replace("<", "&lt;")
    |> String.replace(">", "&gt;")
    |> String.replace("\"", "&quot;")
    |> String.replace("'", "&apos;")
  end
end
