defmodule TartarusTools.Transcript do
  @moduledoc """
  Checks the iex transcripts of a Markdown file (the README) by running them, as doctests do,
  so that they cannot drift from a real session.

  A transcript is a fenced code block with lines that start with `iex> `. An expression starts
  at `iex> ` and continues on `...> ` lines; the lines after it, up to the next `iex> `, are
  what the session shows: what the expression printed, then the inspected value (`inspect/2`
  with `pretty: true, width: 80`, as iex prints it), runs of white space counting as one
  space (a line may be broken where iex breaks it or not). An expression with no lines after it is
  run but not compared. Lines starting with `$ ` (a shell prompt) are skipped. In an expected
  line, `...` matches any text, for what changes from run to run (agent ids, times).

  Expressions of a file run one after another in one binding and environment (variables,
  modules defined, aliases carry over) in the calling process; run it in a fresh VM
  (`nonode@nohost`, as `iex -S mix` is) to see what a user sees.

  ## Examples

      iex> md = "```\\niex> x = 1 + 1\\n2\\niex> IO.puts(x * 10)\\n20\\n:ok\\n```\\n"
      iex> TartarusTools.Transcript.check(md)
      []
      iex> [{:mismatch, "x + 1", "4", "3"}] = TartarusTools.Transcript.check("```\\niex> x = 2\\niex> x + 1\\n4\\n```")
  """

  @typedoc "One expression of a transcript and what the session shows after it."
  @type example :: %{code: String.t(), expected: String.t() | nil}

  @typedoc "A failed expression: its code, what was expected and what it gave."
  @type failure :: {:mismatch | :raised, String.t(), String.t(), String.t()}

  @doc """
  The examples of every transcript in `markdown`, in order (a list per fenced block).

  ## Examples

      iex> TartarusTools.Transcript.examples("text\\n```\\n$ iex -S mix\\niex> a =\\n...>   1\\n1\\n```\\n")
      [[%{code: "a =\\n  1", expected: "1"}]]
  """
  @spec examples(String.t()) :: [[example()]]
  def examples(markdown) do
    markdown
    |> String.split("\n")
    |> blocks([], nil)
    |> Enum.map(&parse_block/1)
    |> Enum.reject(&(&1 == []))
  end

  defp blocks([], acc, _), do: Enum.reverse(acc)

  defp blocks([line | rest], acc, nil) do
    if String.starts_with?(String.trim_leading(line), "```"),
      do: blocks(rest, acc, []),
      else: blocks(rest, acc, nil)
  end

  defp blocks([line | rest], acc, current) do
    if String.starts_with?(String.trim_leading(line), "```"),
      do: blocks(rest, [Enum.reverse(current) | acc], nil),
      else: blocks(rest, acc, [line | current])
  end

  defp parse_block(lines) do
    if Enum.any?(lines, &String.starts_with?(&1, "iex> ")),
      do: lines |> Enum.reduce([], &parse_line/2) |> Enum.reverse() |> Enum.map(&finish/1),
      else: []
  end

  defp parse_line("iex> " <> code, acc), do: [%{code: [code], expected: []} | acc]

  defp parse_line("...> " <> code, [ex | acc]) when ex.expected == [],
    do: [%{ex | code: [code | ex.code]} | acc]

  defp parse_line("$ " <> _, acc), do: acc
  defp parse_line(_line, []), do: []
  defp parse_line(line, [ex | acc]), do: [%{ex | expected: [line | ex.expected]} | acc]

  defp finish(%{code: code, expected: expected}) do
    expected = expected |> Enum.drop_while(&(String.trim(&1) == "")) |> Enum.reverse()

    %{
      code: code |> Enum.reverse() |> Enum.join("\n"),
      expected: if(expected == [], do: nil, else: Enum.join(expected, "\n"))
    }
  end

  @doc """
  Runs every transcript of `markdown` and returns the failures (`[]` when every expected
  output matched). A transcript stops at its first failure; each transcript of the file
  shares the binding of those before it.
  """
  @spec check(String.t()) :: [failure()]
  def check(markdown) do
    {failures, _, _} =
      markdown
      |> examples()
      |> List.flatten()
      |> Enum.reduce_while({[], [], Code.env_for_eval([])}, fn ex, {[], binding, env} ->
        case run(ex, binding, env) do
          {:ok, binding, env} -> {:cont, {[], binding, env}}
          {:error, failure} -> {:halt, {[failure], binding, env}}
        end
      end)

    failures
  end

  @doc """
  Checks the transcripts of the file at `path`; raises naming each failure.
  """
  @spec check_file!(Path.t()) :: :ok
  def check_file!(path) do
    case check(File.read!(path)) do
      [] ->
        :ok

      failures ->
        raise "#{path}: transcript failed:\n" <>
                Enum.map_join(failures, "\n", fn {kind, code, expected, got} ->
                  "#{kind}: iex> #{code}\n  expected:\n#{expected}\n  got:\n#{got}"
                end)
    end
  end

  defp run(%{code: code, expected: expected}, binding, env) do
    {:ok, device} = StringIO.open("")
    leader = Process.group_leader()
    Process.group_leader(self(), device)

    result =
      try do
        {value, binding, env} =
          Code.eval_quoted_with_env(Code.string_to_quoted!(code), binding, env)

        {:ok, value, binding, env}
      rescue
        e -> {:raised, Exception.format(:error, e, __STACKTRACE__)}
      after
        Process.group_leader(self(), leader)
      end

    {_, printed} = StringIO.contents(device)
    StringIO.close(device)

    case result do
      {:raised, message} ->
        {:error, {:raised, code, expected || "", message}}

      {:ok, value, binding, env} ->
        got = printed <> inspect(value, pretty: true, width: 80)

        if expected == nil or matches?(expected, got),
          do: {:ok, binding, env},
          else: {:error, {:mismatch, code, expected, got}}
    end
  end

  defp matches?(expected, got) do
    squeeze = &(&1 |> String.replace(~r/\s+/, " ") |> String.trim())

    pattern =
      expected
      |> squeeze.()
      |> String.split("...")
      |> Enum.map_join(".*?", &Regex.escape/1)

    Regex.match?(~r/\A#{pattern}\z/s, squeeze.(got))
  end
end
