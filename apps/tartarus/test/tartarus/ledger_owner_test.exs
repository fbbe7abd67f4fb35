defmodule Tartarus.LedgerOwnerTest do
  # One owner for a host's ledger (issue 43, item 3): Tartarus.Ledger is the only module that
  # reads or writes the table; every other module of the umbrella (platform, tools, dashboard,
  # emulator, applications, their tests) goes through its documented functions, never `:ets`
  # on the table and never the table itself. And the Ledger's doc lists every key kind its
  # code uses.
  use ExUnit.Case, async: true

  @root Path.expand("../../../..", __DIR__)
  @owner "apps/tartarus/lib/tartarus/ledger.ex"

  # The only places outside the owner that hold the table: the warden builds the host's map
  # with it, and admission's memory (Migration.Protocol) is given it
  # (Ledger.admission_memory/1).
  @allowed [
    {"apps/tartarus/lib/tartarus/host/warden.ex", "ledger: Tartarus.Ledger.new(decided)"},
    {"apps/tartarus/lib/tartarus/migration/protocol.ex", ":ledger"},
    # A zone's own ledger of tags (a map in its state), not a host's.
    {"apps/tartarus_lats_device/lib/tartarus_lats/zone.ex", ""}
  ]

  # An `:ets` call whose table argument names a ledger; a use of a host's `ledger` field
  # (`host.ledger`, `%{ledger: l}`, `ledger: ...`, `:ledger`).
  @raw_call ~r/:ets\.\w+\(\s*[^,]*\bledger\b/
  @handle ~r/\.ledger\b|\bledger:|:ledger\b/

  defp sources do
    (Path.wildcard(Path.join(@root, "apps/*/{lib,test}/**/*.{ex,exs}")) ++
       Path.wildcard(Path.join(@root, "test/**/*.{ex,exs}")))
    |> Enum.map(&Path.relative_to(&1, @root))
    |> Enum.reject(&(&1 == @owner or &1 == Path.relative_to(__ENV__.file, @root)))
  end

  # Code lines (comment lines dropped) that break the rule.
  def offences(path, text) do
    for {line, n} <- Enum.with_index(String.split(text, "\n"), 1),
        not String.starts_with?(String.trim_leading(line), "#"),
        Regex.match?(@raw_call, line) or Regex.match?(@handle, line),
        not Enum.any?(@allowed, fn {p, s} -> p == path and String.contains?(line, s) end),
        do: "#{path}:#{n}: #{String.trim(line)}"
  end

  test "no module but Tartarus.Ledger touches a host's ledger table" do
    files = sources()
    assert length(files) > 100

    found = Enum.flat_map(files, &offences(&1, File.read!(Path.join(@root, &1))))

    assert found == [],
           "raw uses of a host's ledger outside #{@owner}:\n" <> Enum.join(found, "\n")
  end

  test "the check finds a raw write, a raw read and a handle taken from the host's map" do
    assert [_] = offences("x.ex", "    :ets.insert(state.host.ledger, {{:kill, pid}, true})")
    assert [_] = offences("x.ex", "    case :ets.lookup(ledger, {:fwd, id}) do")
    assert [_] = offences("x.ex", "  defp f(%{ledger: l}), do: l")

    assert [] =
             offences(
               "x.ex",
               "    # the host's ledger ({:proc, pid}): :ets.insert(host.ledger, x)"
             )

    assert [] = offences("x.ex", "    Ledger.put_proc(state.host, pid, entry)")
  end

  test "the Ledger's doc lists every key kind its code reads or writes" do
    {:docs_v1, _, _, _, %{"en" => doc}, _, _} = Code.fetch_docs(Tartarus.Ledger)
    code = File.read!(Path.join(@root, @owner))

    # The key of each `:ets` call on a table (`{:tag, ...}`, `{{:tag, ...}, ...}`, `:tag`).
    kinds =
      for [_, tag] <- Regex.scan(~r/:ets\.\w+\([\w.]+, \[?\{?\{?:(\w+)\b/, code),
          uniq: true,
          do: tag

    assert length(kinds) >= 20

    missing = Enum.reject(kinds, &Regex.match?(~r/`\{?:#{&1}\b/, doc))

    assert missing == [],
           "key kinds missing from Tartarus.Ledger's moduledoc: #{inspect(missing)}"
  end
end
