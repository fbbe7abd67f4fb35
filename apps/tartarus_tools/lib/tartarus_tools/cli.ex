defmodule TartarusTools.CLI do
  @moduledoc """
  One way for the umbrella's mix tasks to parse flags, check them and report results, so
  every task answers bad input the same way ("mix tartarus.x: --hosts must be a positive
  integer, got: 0") and prints its JSON the same way (with `--json`, one object on the last
  line).

      opts = TartarusTools.CLI.parse!(argv, [hosts: :integer, json: :boolean], "tartarus.x")
      TartarusTools.CLI.positive!(opts, [:hosts], "tartarus.x")
      TartarusTools.CLI.report(%{hosts: 3}, opts)
  """

  @doc """
  Parses `argv` with `switches` (strict); any unknown flag or stray argument raises
  `Mix.Error` naming the task. Returns the options, or `{options, arguments}` with
  `args: true`.
  """
  @spec parse!([String.t()], keyword(), String.t(), keyword()) ::
          keyword() | {keyword(), [String.t()]}
  def parse!(argv, switches, task, opts \\ []) do
    {parsed, args, invalid} = OptionParser.parse(argv, strict: switches)
    args_ok? = Keyword.get(opts, :args, false)

    if invalid != [] or (args != [] and not args_ok?) do
      bad = Enum.map(invalid, &elem(&1, 0)) ++ if(args_ok?, do: [], else: args)
      Mix.raise("mix #{task}: invalid arguments #{Enum.join(bad, " ")}; see `mix help #{task}`")
    end

    if args_ok?, do: {parsed, args}, else: parsed
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
  line of output), else one `key: value` line per key (or `text.(result)` if given). With
  `out_file: path` also writes the JSON there.
  """
  @spec report(map(), keyword(), (map() -> String.t()) | nil) :: :ok
  def report(result, opts, text \\ nil) do
    json = TartarusTools.JSON.encode!(result)
    if opts[:out_file], do: File.write!(opts[:out_file], json <> "\n")

    cond do
      opts[:json] ->
        Mix.shell().info(json)

      text ->
        Mix.shell().info(text.(result))

      true ->
        Enum.each(Enum.sort(result), fn {k, v} -> Mix.shell().info("  #{k}: #{inspect(v)}") end)
    end
  end

  defp check!(opts, keys, task, ok?, what) do
    for key <- keys, v = opts[key], v != nil, not (is_number(v) and ok?.(v)) do
      Mix.raise("mix #{task}: --#{dash(key)} must be #{what}, got: #{v}")
    end

    :ok
  end

  defp dash(key), do: key |> Atom.to_string() |> String.replace("_", "-")
end
