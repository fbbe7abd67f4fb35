defmodule Tartarus.DoorsTest do
  # docs/architecture.md's table of doors (issue 43): its row for the platform names every
  # module of the app that has a documentation of its own (a door, or a documented
  # internal) and none that is `@moduledoc false` or gone, so a module made public or
  # hidden changes the table too.
  use ExUnit.Case, async: true

  @root Path.expand("../../../..", __DIR__)

  defp documented_modules do
    for path <- Path.wildcard(Path.join(@root, "apps/tartarus/lib/**/*.ex")),
        {:defmodule, _, [{:__aliases__, _, parts}, [do: body]]} <- top_modules(path),
        documented?(body),
        into: MapSet.new(),
        do: Enum.join(parts, ".")
  end

  defp top_modules(path) do
    case Code.string_to_quoted!(File.read!(path)) do
      {:__block__, _, forms} -> forms
      form -> [form]
    end
  end

  # A module attribute `@moduledoc` other than `false` in the module's own body.
  defp documented?(body) do
    forms =
      case body do
        {:__block__, _, forms} -> forms
        form -> [form]
      end

    Enum.any?(forms, &match?({:@, _, [{:moduledoc, _, [doc]}]} when doc != false, &1))
  end

  defp row do
    File.read!(Path.join(@root, "docs/architecture.md"))
    |> String.split("\n")
    |> Enum.find(&String.starts_with?(&1, "| `tartarus` |"))
  end

  test "the platform's row of the doors table names exactly its documented modules" do
    named =
      Regex.scan(~r/`(Tartarus(?:\.[A-Z]\w*)*)`/, row(), capture: :all_but_first)
      |> List.flatten()
      |> MapSet.new()

    documented = documented_modules()
    assert MapSet.size(documented) > 20
    assert Enum.sort(MapSet.difference(documented, named)) == []
    assert Enum.sort(MapSet.difference(named, documented)) == []
  end
end
