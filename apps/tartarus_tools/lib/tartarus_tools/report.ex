defmodule TartarusTools.Report do
  @moduledoc """
  Writes the results of a scenario run into its output directory.

  A run writes, into one directory (by default `default_out_dir/1`):

    * one CSV per series (`write_csv!/4`), RFC 4180 quoting;
    * SVG plots (see `TartarusTools.SVG.write!/2`);
    * `summary.json` and `summary.md` (`write_summary!/3`): the machine-readable keys, and the
      same as a Markdown table with our numbers beside the thesis's.

  Example:

      dir = TartarusTools.Report.default_out_dir("lats")
      TartarusTools.Report.write_csv!(dir, "hops", ["step", "hops"], [[1, 3], [2, 4]])

      TartarusTools.Report.write_summary!(dir, %{seed: 1, queries: 200, mean_hops: 3.4},
        title: "LATS: Where is X",
        comparisons: [%{metric: "mean hops", ours: 3.4, thesis: 3.9}]
      )

  All writers create the directory if needed and return the paths written.
  """

  # The longest nested value summary.md shows in a table cell.
  @long_cell 100

  alias Tartarus.JSON

  @typedoc "One row of an \"ours vs thesis\" table; `:note` is optional."
  @type comparison :: %{metric: term, ours: term, thesis: term}

  @doc """
  Renders rows as CSV text (RFC 4180 quoting: a field containing a comma, quote, CR or LF is
  wrapped in quotes with inner quotes doubled). Lines end in `\\n`; pass
  `line_ending: "\\r\\n"` for strict RFC 4180. Fields may be strings, atoms, numbers or
  `nil` (empty). Every row must have as many fields as the header.

  ## Examples

      iex> TartarusTools.Report.to_csv(["name", "note"], [["a", ~s(say "hi", twice)], [:b, nil]])
      ~s(name,note\\na,"say ""hi"", twice"\\nb,\\n)
  """
  @spec to_csv([term], [[term]], keyword) :: String.t()
  def to_csv(header, rows, opts \\ []) when is_list(header) and is_list(rows) do
    eol = Keyword.get(opts, :line_ending, "\n")
    width = length(header)

    body =
      rows
      |> Enum.with_index(1)
      |> Enum.map(fn
        {row, _i} when is_list(row) and length(row) == width ->
          csv_line(row, eol)

        {row, i} ->
          raise ArgumentError,
                "Report.to_csv/3: expected row #{i} to be a list of #{width} fields " <>
                  "(as many as the header), got: #{inspect(row)}"
      end)

    IO.iodata_to_binary([csv_line(header, eol), body])
  end

  defp csv_line(fields, eol), do: [Enum.map_intersperse(fields, ",", &csv_field/1), eol]

  defp csv_field(nil), do: ""
  defp csv_field(v) when is_integer(v), do: Integer.to_string(v)
  defp csv_field(v) when is_float(v), do: Float.to_string(v)
  defp csv_field(v) when is_atom(v), do: csv_field(Atom.to_string(v))

  defp csv_field(v) when is_binary(v) do
    if String.contains?(v, [",", "\"", "\r", "\n"]),
      do: [?", String.replace(v, "\"", "\"\""), ?"],
      else: v
  end

  defp csv_field(v) do
    raise ArgumentError,
          "Report.to_csv/3: expected fields to be strings, atoms, numbers or nil, got: #{inspect(v)}"
  end

  @doc """
  Writes `dir/name.csv` (`.csv` is added unless `name` has it) and returns its path.
  Options as in `to_csv/3`.
  """
  @spec write_csv!(Path.t(), String.t(), [term], [[term]], keyword) :: Path.t()
  def write_csv!(dir, name, header, rows, opts \\ []) do
    file = if String.ends_with?(name, ".csv"), do: name, else: name <> ".csv"
    write!(dir, safe_name!(file, "write_csv!/5"), to_csv(header, rows, opts))
  end

  @doc """
  Writes `summary.json` and `summary.md` into `dir`; returns `[json_path, md_path]`.

  `summary` is a map of JSON-encodable values (see `Tartarus.JSON`). Options:

    * `:title` - heading of `summary.md` (default `"Summary"`);
    * `:comparisons` - rows `%{metric:, ours:, thesis:}` (optional `:note`) shown in an
      "Ours vs thesis" table and stored under `"comparisons"` in the JSON;
    * `:markdown` - more Markdown (iodata: an experiment's own tables) appended to
      `summary.md` after a blank line (not in the JSON);
    * `:provenance` - `false` to leave out what made the run; by default both files carry
      it (`TartarusTools.Provenance.collect/0`: argv, git commit and dirty flag, OTP and
      Elixir versions, date, machine), under `"provenance"` in the JSON and as a
      "Provenance" table at the end of `summary.md`.
  """
  @spec write_summary!(Path.t(), map, keyword) :: [Path.t()]
  def write_summary!(dir, summary, opts \\ []) when is_map(summary) do
    comparisons = Keyword.get(opts, :comparisons, [])
    Enum.each(comparisons, &check_comparison!/1)

    json =
      case comparisons do
        [] ->
          summary

        _ ->
          if Map.has_key?(summary, :comparisons) or Map.has_key?(summary, "comparisons") do
            raise ArgumentError,
                  "Report.write_summary!/3: expected the summary to have no \"comparisons\" key " <>
                    "when the :comparisons option is given"
          end

          Map.put(summary, "comparisons", comparisons)
      end

    {json, opts} =
      if Keyword.get(opts, :provenance, true) and not Map.has_key?(summary, :provenance) and
           not Map.has_key?(summary, "provenance") do
        provenance = TartarusTools.Provenance.collect()
        more =
          case Keyword.get(opts, :markdown) do
            nil -> provenance_markdown(provenance)
            md -> [md, "\n", provenance_markdown(provenance)]
          end

        {Map.put(json, "provenance", provenance), Keyword.put(opts, :markdown, more)}
      else
        {json, opts}
      end

    [
      write!(dir, "summary.json", [JSON.encode_to_iodata!(json, pretty: true), "\n"]),
      write!(dir, "summary.md", summary_markdown(summary, opts))
    ]
  end

  @doc """
  Renders the Markdown of `summary.md` (see `write_summary!/3`). Keys are sorted; nested
  values are shown as compact JSON while that stays short (#{@long_cell} characters); a
  longer one (a sweep's aggregates, an arm per key) gets a section of its own after the
  table, named in its row: a map or list of records (maps of short values) as one table
  with a column per field, any other map as a key-value table with its long values in
  sections below it. `|` in cells is escaped; `:markdown` is appended.

  ## Examples

      iex> TartarusTools.Report.summary_markdown(%{seed: 1, hops: 3.5}, comparisons: [%{metric: "hops", ours: 3.5, thesis: 4}])
      "# Summary\\n\\n| key | value |\\n|---|---|\\n| hops | 3.5 |\\n| seed | 1 |\\n\\n## Ours vs thesis\\n\\n| metric | ours | thesis |\\n|---|---|---|\\n| hops | 3.5 | 4 |\\n"
      iex> TartarusTools.Report.summary_markdown(%{seed: 1}, title: "Run", markdown: "## Laps\\n")
      "# Run\\n\\n| key | value |\\n|---|---|\\n| seed | 1 |\\n\\n## Laps\\n"
  """
  @spec summary_markdown(map, keyword) :: String.t()
  def summary_markdown(summary, opts \\ []) when is_map(summary) do
    title = Keyword.get(opts, :title, "Summary")
    comparisons = Keyword.get(opts, :comparisons, [])

    {rows, sections} = key_table(summary, "", 2)

    compare =
      case comparisons do
        [] ->
          []

        _ ->
          notes? = Enum.any?(comparisons, &Map.has_key?(&1, :note))

          head =
            if notes?,
              do: "| metric | ours | thesis | note |\n|---|---|---|---|\n",
              else: "| metric | ours | thesis |\n|---|---|---|\n"

          lines =
            Enum.map(comparisons, fn c ->
              note = if notes?, do: [" | ", cell(Map.get(c, :note, ""))], else: []
              ["| ", cell(c.metric), " | ", cell(c.ours), " | ", cell(c.thesis), note, " |\n"]
            end)

          ["\n## Ours vs thesis\n\n", head, lines]
      end

    more =
      case Keyword.get(opts, :markdown) do
        nil -> []
        md -> ["\n", md]
      end

    IO.iodata_to_binary([
      "# ",
      title,
      "\n\n| key | value |\n|---|---|\n",
      rows,
      compare,
      sections,
      more
    ])
  end

  # The rows of a key-value table of `map` (keys sorted), and the sections of its values too
  # long for a cell (`path` names them: "sweep", "sweep.aggregates").
  defp key_table(map, path, level) do
    entries = map |> Enum.map(fn {k, v} -> {to_string(k), v} end) |> Enum.sort()

    rows =
      Enum.map(entries, fn {k, v} ->
        shown = if long?(v), do: "see #{name(path, k)} below", else: v
        ["| ", cell(k), " | ", cell(shown), " |\n"]
      end)

    sections = for {k, v} <- entries, long?(v), do: section(name(path, k), v, level)
    {rows, sections}
  end

  defp name("", key), do: key
  defp name(path, key), do: path <> "." <> key

  defp section(title, value, level) do
    heading = ["\n", String.duplicate("#", min(level, 4)), " ", title, "\n"]

    case records(value) do
      {:ok, labels?, columns, rows} ->
        head = if labels?, do: ["key" | columns], else: columns

        lines =
          for {label, record} <- rows do
            cells = for c <- columns, do: cell(Map.get(record, c))
            cells = if labels?, do: [cell(label) | cells], else: cells
            ["| ", Enum.intersperse(cells, " | "), " |\n"]
          end

        [
          heading,
          "\n| ",
          Enum.intersperse(Enum.map(head, &cell/1), " | "),
          " |\n|",
          String.duplicate("---|", length(head)),
          "\n",
          lines
        ]

      :error ->
        map = if is_list(value), do: value |> Enum.with_index() |> Map.new(fn {v, i} -> {i, v} end), else: value
        {rows, sections} = key_table(map, title, level + 1)
        # A map of long values only (a sweep's arms) is its sections alone.
        table = if length(sections) < map_size(map), do: ["\n| key | value |\n|---|---|\n", rows], else: []
        [heading, table, sections]
    end
  end

  # A map or list whose values are all maps (not structs) of short scalars and lists:
  # records, shown as one table. Columns are the fields' names as strings, in the order they first appear.
  defp records(value) do
    items =
      cond do
        is_map(value) -> value |> Enum.map(fn {k, v} -> {to_string(k), v} end) |> Enum.sort()
        is_list(value) -> Enum.map(value, &{nil, &1})
      end

    record? = fn v ->
      plain_map?(v) and map_size(v) > 0 and
        not Enum.any?(v, fn {_, x} -> plain_map?(x) or long?(x) end)
    end

    if items != [] and Enum.all?(items, fn {_, v} -> record?.(v) end) do
      rows = for {label, v} <- items, do: {label, Map.new(v, fn {k, x} -> {to_string(k), x} end)}
      columns = rows |> Enum.flat_map(fn {_, r} -> r |> Map.keys() |> Enum.sort() end) |> Enum.uniq()
      {:ok, is_map(value), columns, rows}
    else
      :error
    end
  end

  defp plain_map?(v), do: is_map(v) and not is_struct(v)

  defp long?(v) when is_list(v), do: String.length(cell(v)) > @long_cell
  defp long?(v), do: plain_map?(v) and String.length(cell(v)) > @long_cell

  @doc """
  The "Provenance" section of `summary.md`: one row per key of `provenance` (see
  `TartarusTools.Provenance.collect/0`), the command line as typed.

      iex> TartarusTools.Report.provenance_markdown(%{argv: ["mix", "tartarus.x", "--seed", "1"], git_commit: "abc", git_dirty: false})
      "## Provenance\\n\\n| key | value |\\n|---|---|\\n| argv | `mix tartarus.x --seed 1` |\\n| git_commit | abc |\\n| git_dirty | false |\\n"
  """
  @spec provenance_markdown(map) :: String.t()
  def provenance_markdown(provenance) do
    rows =
      provenance
      |> Enum.map(fn
        {:argv, argv} -> {"argv", "`" <> Enum.join(argv, " ") <> "`"}
        {k, v} -> {to_string(k), v}
      end)
      |> Enum.sort()
      |> Enum.map(fn {k, v} -> ["| ", cell(k), " | ", cell(v), " |\n"] end)

    IO.iodata_to_binary(["## Provenance\n\n| key | value |\n|---|---|\n", rows])
  end

  defp check_comparison!(%{metric: _, ours: _, thesis: _}), do: :ok

  defp check_comparison!(other) do
    raise ArgumentError,
          "Report.write_summary!/3: expected comparisons %{metric:, ours:, thesis:}, got: " <>
            inspect(other)
  end

  defp cell(v) when is_binary(v),
    do: v |> String.replace("|", "\\|") |> String.replace(~r/\R/, " ")

  defp cell(nil), do: ""
  defp cell(v) when is_atom(v) or is_number(v), do: cell(to_string(v))
  defp cell(v) when is_map(v) or is_list(v), do: cell(JSON.encode!(v))
  defp cell(v), do: cell(inspect(v))

  @doc """
  The default output directory of a run, `results/<scenario>-<UTC timestamp>`. `scenario`
  must be a plain name (letters, digits, `_`, `-`, `.`), so it can never escape `results/`.

  ## Examples

      iex> TartarusTools.Report.default_out_dir("lats", ~U[2024-03-01 09:05:07Z])
      "results/lats-20240301-090507"
  """
  @spec default_out_dir(String.t() | atom, DateTime.t()) :: Path.t()
  def default_out_dir(scenario, now \\ machine_now()) do
    name = safe_name!(to_string(scenario), "default_out_dir/2")
    stamp = Calendar.strftime(now, "%Y%m%d-%H%M%S")
    Path.join("results", "#{name}-#{stamp}")
  end

  # The machine's wall clock (an output directory names when the run was made, in either
  # mode of Tartarus.Clock).
  defp machine_now,
    do: DateTime.from_unix!(Tartarus.Clock.machine_system_time(:microsecond), :microsecond)

  defp safe_name!(name, fun) do
    if Regex.match?(~r/\A[A-Za-z0-9_.\-]+\z/, name) and name not in [".", ".."] do
      name
    else
      raise ArgumentError,
            "Report.#{fun}: expected a plain name of letters, digits, _ - and ., got: " <>
              inspect(name)
    end
  end

  defp write!(dir, file, content) do
    File.mkdir_p!(dir)
    path = Path.join(dir, file)
    File.write!(path, content)
    path
  end
end
