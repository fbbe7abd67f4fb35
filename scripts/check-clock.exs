# Lists every direct reading of time, timer, sleep and `receive ... after` under apps/*/lib
# that does not go through Tartarus.Clock (apps/tartarus/lib/tartarus/clock.ex), except the
# ones scripts/clock-allowlist names, each with its reason. Exits 1 when it finds any other.
#
#   elixir scripts/check-clock.exs            # the check (scripts/test runs it)
#   elixir scripts/check-clock.exs --all      # every use, allowed or not, and the counts
#
# Allowlist lines: `path | a piece of the line | reason` (`#` comments, blank lines ignored).
# An entry that matches nothing any more is reported too, so the list stays true.
defmodule CheckClock do
  @patterns [
    ~r/\bSystem\.(monotonic_time|system_time|os_time)\b/,
    ~r/:os\.(system_time|timestamp)\b/,
    ~r/:erlang\.(monotonic_time|system_time|send_after|start_timer|cancel_timer|read_timer)\b/,
    ~r/\bProcess\.(send_after|sleep|cancel_timer|read_timer)\b/,
    ~r/:timer\.(sleep|send_after|send_interval|apply_after|apply_interval|tc|exit_after|kill_after)\b/,
    ~r/\b(Naive)?DateTime\.utc_now\b/,
    ~r/:calendar\.(local_time|universal_time)\b/,
    ~r/:state_timeout\b/,
    ~r/\bafter\s+[^\s,()]+\s*->/
  ]
  @own ["apps/tartarus/lib/tartarus/clock.ex", "apps/tartarus/lib/tartarus/clock/virtual.ex"]

  def main(args) do
    root = Path.expand("..", __DIR__)
    File.cd!(root)
    allow = read_allowlist("scripts/clock-allowlist")

    uses =
      for path <- Path.wildcard("apps/*/lib/**/*.{ex,exs}") |> Enum.sort(),
          path not in @own,
          use <- uses(path),
          do: use

    {allowed, direct} =
      Enum.split_with(uses, fn {path, _n, line} ->
        Enum.any?(allow, fn {p, piece, _} -> p == path and String.contains?(line, piece) end)
      end)

    stale =
      Enum.reject(allow, fn {p, piece, _} ->
        Enum.any?(uses, fn {path, _, line} -> p == path and String.contains?(line, piece) end)
      end)

    if "--all" in args do
      Enum.each(allowed, fn {p, n, l} -> IO.puts("allowed  #{p}:#{n}: #{String.trim(l)}") end)
    end

    Enum.each(direct, fn {p, n, l} -> IO.puts("direct   #{p}:#{n}: #{String.trim(l)}") end)

    Enum.each(stale, fn {p, piece, _} -> IO.puts("stale    #{p} | #{piece} (matches nothing)") end)

    IO.puts(
      "check-clock: #{length(direct)} direct use(s) of time outside Tartarus.Clock, " <>
        "#{length(allowed)} allowed (scripts/clock-allowlist, #{length(allow)} entries)"
    )

    if direct != [] or stale != [], do: System.halt(1)
  end

  defp read_allowlist(file) do
    file
    |> File.read!()
    |> String.split("\n")
    |> Enum.map(&String.trim/1)
    |> Enum.reject(&(&1 == "" or String.starts_with?(&1, "#")))
    |> Enum.map(fn line ->
      case String.split(line, " | ", parts: 3) do
        [p, piece, reason] when reason != "" -> {p, piece, reason}
        _ -> raise "#{file}: expected `path | piece | reason`, got: #{line}"
      end
    end)
  end

  defp uses(path) do
    lines = path |> File.read!() |> String.split("\n")
    indexed = Enum.with_index(lines, 1)

    single =
      for {line, n} <- indexed,
          not comment?(line),
          Enum.any?(@patterns, &Regex.match?(&1, line)),
          not zero_after?(line),
          not (Regex.match?(~r/\bafter\s+[^\s,()]+\s*->/, line) and
                 Regex.match?(~r/Clock\.receive/, line)),
          do: {path, n, line}

    # `receive ... after` with the timeout on the next line (a `try ... after` has no `->`).
    multi =
      for {{line, n}, {next, _}} <- Enum.zip(indexed, tl(indexed) ++ [{"", 0}]),
          Regex.match?(~r/^\s*after\s*$/, line),
          Regex.match?(~r/^\s*[^\s#].*->/, next),
          not Regex.match?(~r/^\s*(0|:infinity)\s*->/, next),
          not clock_receive?(lines, n),
          do: {path, n + 1, "after " <> String.trim(next)}

    Enum.sort_by(single ++ multi, &elem(&1, 1))
  end

  # The `after` at line n closes a `Tartarus.Clock.receive` (the nearest `receive do` above).
  defp clock_receive?(lines, n) do
    lines
    |> Enum.take(n - 1)
    |> Enum.reverse()
    |> Enum.find(&Regex.match?(~r/\breceive\s+do\b/, &1))
    |> case do
      nil -> false
      line -> Regex.match?(~r/Clock\.receive\s+do/, line)
    end
  end

  defp comment?(line), do: Regex.match?(~r/^\s*#/, line)

  defp zero_after?(line),
    do:
      Regex.match?(~r/\bafter\s+(0|:infinity)\s*->/, line) and
        not Enum.any?(Enum.drop(@patterns, -1), &Regex.match?(&1, line))
end

CheckClock.main(System.argv())
