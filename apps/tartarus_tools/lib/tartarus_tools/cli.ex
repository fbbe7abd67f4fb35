defmodule TartarusTools.CLI do
  @moduledoc """
  One way for the umbrella's mix tasks to parse flags, check them and report results, so
  every task answers bad input the same way ("mix tartarus.x: --hosts must be a positive
  integer, got: 0") and prints its JSON the same way (with `--json`, one object on the last
  line).

      opts = TartarusTools.CLI.parse!(argv, [hosts: :integer, json: :boolean], "tartarus.x")
      TartarusTools.CLI.positive!(opts, [:hosts], "tartarus.x")
      TartarusTools.CLI.report(%{hosts: 3}, opts)

  ## Tasks

  A task writes `use TartarusTools.CLI` instead of `use Mix.Task`: it is then a Mix task
  that answers `--help` (or `-h`) anywhere in its arguments by printing its `@moduledoc`,
  without running, and that checks its `--out` before anything runs (`check_out/2`): a
  directory by default, a file with `use TartarusTools.CLI, out: :file`, not at all with
  `out: false`. An `--out` that cannot be written is refused in one line, so a long run
  does not end in a stack trace when it writes its results.

  A task whose options are a `Tartarus.Options` schema parses them with `options!/3`: the
  flags come from the schema's keys (`state_bytes` is `--state-bytes`), the defaults from
  the schema (the scenario's own, when it has one), and errors use the schema's words.

  ## The convention

    * every user error is one line, `mix TASK: ...`, naming the flag as typed and what is
      wrong: `missing value for --seed`, `unknown flag --bogus`, `invalid value for
      --nodes: expected a positive integer, got: 0`, `--topology: file not found: PATH`;
      it is a `Mix.Error`, which Mix prints without a stack trace and exits with status 1.
      An experiment's own validation message goes through `error!/2`, which rewrites its
      `:keys` as `--flags` and drops the module it names;
    * `--help` shows options as flags (`flag_docs/1`);
    * `--json` prints the summary as one JSON object, the last line, with its
      `provenance` (`TartarusTools.Provenance`); so does every `summary.json`;
    * text output shows values for a person (`show/1`); a run that checks something ends
      with a verdict line (`mix tartarus.chaos`);
    * repetitions over seeds are `--seeds N` (seeds `--seed`, `--seed` + 1, ...);
    * long runs draw "what, k of n, elapsed, ETA" on standard error when it is a terminal
      and `--json` is not given (`TartarusTools.Progress`, `TartarusEmu.Sweep`);
      `--progress`, which every task takes, draws them in every case, also with `--json`
      and into a log file (there a plain line at most every 10 s, and a sweep's line per
      run): for runs of hours started with `nohup ... 2> log`.
  """

  @doc false
  defmacro __using__(opts) do
    out = Keyword.get(opts, :out, :dir)

    quote do
      use Mix.Task
      @tartarus_cli_out unquote(out)
      @before_compile TartarusTools.CLI
    end
  end

  @doc false
  defmacro __before_compile__(_env) do
    quote do
      defoverridable run: 1

      @impl Mix.Task
      def run(argv) do
        task = Mix.Task.task_name(__MODULE__)
        TartarusTools.Provenance.record_command(task, argv)

        if TartarusTools.CLI.help?(argv) do
          TartarusTools.CLI.help(__MODULE__)
        else
          TartarusTools.CLI.out!(argv, @tartarus_cli_out, task)
          super(TartarusTools.CLI.progress!(argv))
        end
      end
    end
  end

  @doc """
  Takes the flag every task has, `--progress`, out of `argv`: when it is there, asks for
  progress lines in this VM (`TartarusTools.Progress.force/1`) and returns `argv` without
  it; the task's own parser never sees it.

      iex> TartarusTools.CLI.progress!(["--seed", "3"])
      ["--seed", "3"]
  """
  @spec progress!([String.t()]) :: [String.t()]
  def progress!(argv) do
    if "--progress" in argv do
      :ok = TartarusTools.Progress.force(true)
      Enum.reject(argv, &(&1 == "--progress"))
    else
      argv
    end
  end

  @doc """
  Refuses, in one line naming `--out`, an `--out PATH` in `argv` that cannot be written as
  `kind` (`:dir` or `:file`; `false`: no check). See `check_out/2`. An `--out` without a
  value is left to the task's parser.
  """
  @spec out!([String.t()], :dir | :file | false, String.t()) :: :ok
  def out!(_argv, false, _task), do: :ok

  def out!(argv, kind, task) do
    with path when is_binary(path) <- out_arg(argv),
         {:error, why} <- check_out(path, kind) do
      Mix.raise("mix #{task}: --out #{path}: #{why}")
    else
      _ -> :ok
    end
  end

  defp out_arg(["--out", value | _]), do: if(String.starts_with?(value, "--"), do: nil, else: value)
  defp out_arg(["--out=" <> value | _]), do: value
  defp out_arg([_ | rest]), do: out_arg(rest)
  defp out_arg([]), do: nil

  @doc """
  Whether a task can write its output at `path`, checked before its run and without
  creating anything: as a directory (`:dir`), `path` is a writable directory, or does not
  exist and its nearest existing ancestor is a writable directory (the task creates the
  rest); as a file (`:file`), `path` is not a directory and its directory is writable (or
  can be made so). Writability is tried, not read from permission bits: a file is created
  in the directory and removed again.

      iex> TartarusTools.CLI.check_out(System.tmp_dir!(), :dir)
      :ok
      iex> TartarusTools.CLI.check_out(System.tmp_dir!(), :file)
      {:error, "is a directory, expected a file"}
  """
  @spec check_out(Path.t(), :dir | :file) :: :ok | {:error, String.t()}
  def check_out(path, kind) do
    full = Path.expand(path)

    case {File.stat(full), kind} do
      {{:ok, %{type: :directory}}, :dir} -> probe(full)
      {{:ok, %{type: :directory}}, :file} -> {:error, "is a directory, expected a file"}
      {{:ok, _}, :dir} -> {:error, "exists and is not a directory"}
      {{:ok, _}, :file} -> probe(Path.dirname(full))
      {{:error, reason}, _} when reason in [:enoent, :enotdir] -> creatable(Path.dirname(full))
      {{:error, reason}, _} -> {:error, "cannot be read (#{:file.format_error(reason)})"}
    end
  end

  # A directory to be created: the nearest existing ancestor must be a writable directory.
  defp creatable(dir) do
    case File.stat(dir) do
      {:ok, %{type: :directory}} ->
        probe(dir)

      {:ok, _} ->
        {:error, "cannot be created: #{dir} is not a directory"}

      {:error, reason} when reason in [:enoent, :enotdir] ->
        if Path.dirname(dir) == dir, do: {:error, "cannot be created"}, else: creatable(Path.dirname(dir))

      {:error, reason} ->
        {:error, "cannot be created: #{dir}: #{:file.format_error(reason)}"}
    end
  end

  defp probe(dir) do
    file = Path.join(dir, ".tartarus-out-check-#{System.unique_integer([:positive])}")

    case File.write(file, "") do
      :ok ->
        File.rm(file)
        :ok

      {:error, reason} ->
        {:error, "cannot write in #{dir} (#{:file.format_error(reason)})"}
    end
  end

  @doc """
  True if `argv` asks for help (`--help` or `-h`).

      iex> TartarusTools.CLI.help?(["--seed", "3", "--help"])
      true
      iex> TartarusTools.CLI.help?(["--seed", "3"])
      false
  """
  @spec help?([String.t()]) :: boolean()
  def help?(argv), do: Enum.any?(argv, &(&1 in ["--help", "-h"]))

  @doc """
  Prints the documentation of the task `module` (its `@moduledoc`, after a line with its
  name and `@shortdoc`), as `mix help TASK` would.
  """
  @spec help(module()) :: :ok
  def help(module) do
    name = Mix.Task.task_name(module)

    doc =
      case Mix.Task.moduledoc(module) do
        doc when is_binary(doc) -> doc
        _ -> "(no documentation)"
      end

    short = Mix.Task.shortdoc(module)
    # Option bullets read as flags, as typed (`--seed`, not `:seed`).
    doc = Regex.replace(~r/^(\s*\* )`:(\w+)`/m, doc, fn _, bullet, key -> bullet <> "`--#{dash(String.to_atom(key))}`" end)

    doc =
      if doc =~ "--dashboard",
        do: doc <> "\n`--dashboard-keep` keeps the page after the run: its last state and charts stay readable until you stop the task (Ctrl-C).\n",
        else: doc

    doc =
      doc <>
        "\n`--progress` (every task) draws progress lines on standard error also with `--json` or into a file (there a line at most every 10 s).\n"

    Mix.shell().info("mix #{name}#{if short, do: " - " <> short, else: ""}\n\n" <> doc)
  end

  @doc """
  Parses `argv` against a `Tartarus.Options` schema: each key is a flag (`:state_bytes` is
  `--state-bytes`; `:integer`-like types parse as integers, `:number`, `:probability` and `{:range, lo, hi}` as
  floats, `:boolean` as a switch, a choice among atoms (`{:in, [:virtual, :peer]}`) as the
  atom its string names, the rest as strings), then the values are validated with
  `Tartarus.Options.validate/3` and the schema's defaults filled in. Raises `Mix.Error`
  naming the task, the flag, what was expected and what arrived.

      iex> schema = [seed: [type: :pos_integer, default: 1], out: [type: :string, default: "results"]]
      iex> TartarusTools.CLI.options!(["--seed", "3"], schema, "tartarus.x")
      [seed: 3, out: "results"]
      iex> schema = [mode: [type: {:in, [:virtual, :peer]}, default: :virtual]]
      iex> TartarusTools.CLI.options!(["--mode", "peer"], schema, "tartarus.x")
      [mode: :peer]
      iex> TartarusTools.CLI.options!([], schema, "tartarus.x")
      [mode: :virtual]

  `synonyms: [seeds: :trials]` accepts `--seeds` as another name of `--trials` (one
  convention across tasks, the old name kept):

      iex> schema = [trials: [type: :pos_integer, default: 10]]
      iex> TartarusTools.CLI.options!(["--seeds", "3"], schema, "tartarus.x", synonyms: [seeds: :trials])
      [trials: 3]
  """
  @spec options!([String.t()], Tartarus.Options.schema(), String.t(), keyword()) :: keyword()
  def options!(argv, schema, task, opts \\ []) do
    synonyms = Keyword.get(opts, :synonyms, [])
    switches = for {key, spec} <- schema, do: {key, switch(spec[:type])}
    switches = switches ++ for {other, key} <- synonyms, do: {other, switches[key]}

    opts =
      for {key, value} <- parse!(argv, switches, task) do
        {Keyword.get(synonyms, key, key), value}
      end

    opts =
      for {key, value} <- opts do
        case schema[key][:type] do
          {:in, choices} when is_binary(value) ->
            if Enum.all?(choices, &is_atom/1),
              do: {key, choice!(value, choices, key, task, nil)},
              else: {key, value}

          _ ->
            {key, value}
        end
      end

    case Tartarus.Options.validate(opts, schema, "mix #{task}") do
      {:ok, opts} ->
        opts

      {:error, message} ->
        # The flag named as typed: `--seeds`, when that is what was given for `:trials`.
        typed =
          for {other, key} <- synonyms,
              Enum.any?(argv, &String.starts_with?(&1, "--#{dash(other)}")),
              reduce: message do
            message -> String.replace(message, ":#{key}", ":#{other}")
          end

        error!(task, typed)
    end
  end

  defp switch(t) when t in [:integer, :pos_integer, :non_neg_integer, :pos_integer_or_infinity],
    do: :integer

  defp switch(t) when t in [:number, :probability], do: :float
  defp switch({:range, _lo, _hi}), do: :float
  defp switch(:boolean), do: :boolean
  defp switch(_), do: :string

  @doc """
  Parses `argv` with `switches` (strict); any unknown flag or stray argument raises
  `Mix.Error` naming the task. Returns the options, or `{options, arguments}` with
  `args: true`. A task with a `--dashboard` switch also takes `--dashboard-keep`, which
  keeps its page after the run (`TartarusDashboard.keep_pages/0`).
  """
  @spec parse!([String.t()], keyword(), String.t(), keyword()) ::
          keyword() | {keyword(), [String.t()]}
  def parse!(argv, switches, task, opts \\ []) do
    # Every task that serves a page (`--dashboard`) may keep it after its run.
    keep? = Keyword.has_key?(switches, :dashboard) and not Keyword.has_key?(switches, :dashboard_keep)
    switches = if keep?, do: switches ++ [dashboard_keep: :boolean], else: switches
    {parsed, args, invalid} = OptionParser.parse(argv, strict: switches)

    parsed =
      if keep? do
        if parsed[:dashboard_keep], do: TartarusDashboard.keep_pages()
        Keyword.delete(parsed, :dashboard_keep)
      else
        parsed
      end

    args_ok? = Keyword.get(opts, :args, false)

    for {flag, value} <- invalid do
      case switch_type(switches, flag) do
        # A known flag with a value of the wrong type: name the flag, the type and the value.
        type when type != nil and value != nil ->
          Mix.raise(
            "mix #{task}: invalid value for #{flag}: expected #{type_words(type)}, got: #{inspect(value)}"
          )

        # A known flag given last, or followed by another flag: its value is missing.
        type when type != nil ->
          Mix.raise("mix #{task}: missing value for #{flag}: expected #{type_words(type)}")

        nil ->
          Mix.raise("mix #{task}: unknown flag #{flag}; see `mix help #{task}` or --help")
      end
    end

    if args != [] and not args_ok? do
      Mix.raise(
        "mix #{task}: unexpected argument #{Enum.join(args, " ")}; see `mix help #{task}` or --help"
      )
    end

    if args_ok?, do: {parsed, args}, else: parsed
  end

  @doc """
  The documentation of a `Tartarus.Options` schema as a task's `--help` shows it: one bullet
  per flag, named as typed (`--state-bytes`, not `:state_bytes`), with its doc, whether it
  is required and its default.

      iex> TartarusTools.CLI.flag_docs(seed: [type: :pos_integer, default: 1, doc: "seed"])
      "  * `--seed` - seed. Defaults to `1`."
  """
  @spec flag_docs(Tartarus.Options.schema()) :: String.t()
  def flag_docs(schema) do
    Regex.replace(~r/^(\s*\* )`:(\w+)`/m, Tartarus.Options.docs(schema), fn _, bullet, key ->
      bullet <> "`--" <> String.replace(key, "_", "-") <> "`"
    end)
  end

  @doc """
  Raises `Mix.Error` with a one-line message for `task`, whatever `reason` is: a message
  from an experiment's validation (its `:key` words read as `--flag`s, and the module and
  function it names are dropped, as in "invalid options given to
  TartarusLats.Experiment.run/1 for key :nodes") or any other term (inspected).

      iex> TartarusTools.CLI.error!("tartarus.x", "invalid options given to TartarusX.Experiment.run/1 for key :state_bytes: expected a positive integer, got: 0")
      ** (Mix.Error) mix tartarus.x: invalid value for --state-bytes: expected a positive integer, got: 0
  """
  @spec error!(String.t(), term()) :: no_return()
  def error!(task, reason) do
    message = if is_binary(reason), do: reason, else: inspect(reason)

    message =
      message
      |> then(
        &Regex.replace(
          ~r/invalid options given to (mix )?[\w.]+(\/\d+)? for key :(\w+)/,
          &1,
          fn _, _, _, key -> "invalid value for --#{String.replace(key, "_", "-")}" end
        )
      )
      |> then(&Regex.replace(~r/required option :(\w+) not given.*$/, &1, fn _, key ->
        "missing required flag --#{String.replace(key, "_", "-")}"
      end))
      |> then(&Regex.replace(~r/ given to (mix [\w.]+|[A-Z][\w.]*\/\d+)/, &1, ""))
      |> then(
        &Regex.replace(~r/(for key|option|key) :(\w+)/, &1, fn _, word, key ->
          word = if word == "for key", do: "for ", else: if(word == "key", do: "", else: "option ")
          word <> "--" <> String.replace(key, "_", "-")
        end)
      )
      |> String.replace(~r/\R+/, " ")
      |> String.trim()

    prefix = "mix #{task}: "
    Mix.raise(if String.starts_with?(message, prefix), do: message, else: prefix <> message)
  end

  @doc "Raises unless each of `keys` given in `opts` is a positive integer."
  @spec positive!(keyword(), [atom()], String.t()) :: :ok
  def positive!(opts, keys, task), do: check!(opts, keys, task, &(&1 > 0), "a positive integer")

  @doc "Raises unless each of `keys` given in `opts` is a non-negative integer."
  @spec non_negative!(keyword(), [atom()], String.t()) :: :ok
  def non_negative!(opts, keys, task),
    do: check!(opts, keys, task, &(&1 >= 0), "a non-negative integer")

  @doc "Raises unless each of `keys` given in `opts` is a number between 0 and 1."
  @spec probability!(keyword(), [atom()], String.t()) :: :ok
  def probability!(opts, keys, task),
    do: check!(opts, keys, task, &(&1 >= 0 and &1 <= 1), "a number between 0 and 1")

  @doc """
  The atom for a flag's string value among `choices` (atoms), or `default` when absent.

      iex> TartarusTools.CLI.choice!("peer", [:virtual, :peer], :mode, "tartarus.x", :virtual)
      :peer
  """
  @spec choice!(String.t() | nil, [atom()], atom(), String.t(), atom()) :: atom()
  def choice!(nil, _choices, _flag, _task, default), do: default

  def choice!(value, choices, flag, task, _default) do
    Enum.find(choices, &(Atom.to_string(&1) == value)) ||
      Mix.raise(
        "mix #{task}: --#{dash(flag)} must be #{Enum.join(choices, " or ")}, got: #{value}"
      )
  end

  @doc """
  Reports a result map: with `json: true` in `opts` prints it as one JSON object (the last
  line of output), else one `key: value` line per key (values as `show/1` shows them), or
  `text.(result)` if given. With
  `out_file: path` also writes the JSON there. The JSON carries what made the result
  under `"provenance"` (`TartarusTools.Provenance.collect/0`) unless the result has that
  key already or `provenance: false` is given.
  """
  @spec report(map(), keyword(), (map() -> String.t()) | nil) :: :ok
  def report(result, opts, text \\ nil) do
    json =
      if (opts[:json] || opts[:out_file]) && Keyword.get(opts, :provenance, true) &&
           not Map.has_key?(result, :provenance) && not Map.has_key?(result, "provenance"),
         do: Tartarus.JSON.encode!(Map.put(result, :provenance, TartarusTools.Provenance.collect())),
         else: Tartarus.JSON.encode!(result)

    if opts[:out_file], do: File.write!(opts[:out_file], json <> "\n")

    cond do
      opts[:json] ->
        Mix.shell().info(json)

      text ->
        Mix.shell().info(text.(result))

      true ->
        Enum.each(Enum.sort(result), fn {k, v} -> Mix.shell().info("  #{k}: #{show(v)}") end)
    end
  end

  @doc """
  A value as a task's text output shows it to a person: floats to at most 4 decimals,
  maps with their keys in numeric order when they are numbers (`"2"` before `"10"`),
  lists and maps without Elixir's syntax, `nil` as `-`.

      iex> TartarusTools.CLI.show(0.9940000000000001)
      "0.994"
      iex> TartarusTools.CLI.show(%{"10" => 2.5, "2" => 1.0, "1" => nil})
      "{1: -, 2: 1.0, 10: 2.5}"
      iex> TartarusTools.CLI.show([[1, 2], [3]])
      "[[1, 2], [3]]"
      iex> TartarusTools.CLI.show(%{"path1" => [12.25, 11.0], mode: :virtual})
      "{mode: virtual, path1: [12.25, 11.0]}"
  """
  @spec show(term()) :: String.t()
  def show(nil), do: "-"
  def show(x) when is_float(x), do: x |> Float.round(4) |> Float.to_string()
  def show(x) when is_integer(x) or is_atom(x) or is_binary(x), do: to_string(x)
  def show(list) when is_list(list), do: "[" <> Enum.map_join(list, ", ", &show/1) <> "]"

  def show(map) when is_map(map) and not is_struct(map) do
    items =
      map
      |> Enum.sort_by(fn {k, _} -> key_order(k) end)
      |> Enum.map_join(", ", fn {k, v} -> "#{show(k)}: #{show(v)}" end)

    "{" <> items <> "}"
  end

  def show(x), do: inspect(x)

  # Numeric keys (numbers, or strings of digits) first in numeric order, then the rest.
  defp key_order(k) when is_number(k), do: {0, k, ""}

  defp key_order(k) do
    text = to_string(k)

    case Integer.parse(text) do
      {n, ""} -> {0, n, ""}
      _ -> {1, 0, text}
    end
  end

  defp switch_type(switches, "--" <> flag) do
    Enum.find_value(switches, fn {key, type} -> if dash(key) == flag, do: type end)
  end

  defp switch_type(_switches, _flag), do: nil

  defp type_words(:integer), do: "an integer"
  defp type_words(:float), do: "a number"
  defp type_words(type), do: "a #{type}"

  defp check!(opts, keys, task, ok?, what) do
    for key <- keys, v = opts[key], v != nil, not (is_number(v) and ok?.(v)) do
      Mix.raise("mix #{task}: --#{dash(key)} must be #{what}, got: #{v}")
    end

    :ok
  end

  defp dash(key), do: key |> Atom.to_string() |> String.replace("_", "-")
end
