defmodule TartarusTools.ReadmeTest do
  # The README's iex transcripts, run in a fresh VM as `iex -S mix` starts one (a node not
  # distributed, the umbrella's applications started), so they cannot drift from a session.
  use ExUnit.Case, async: true

  doctest TartarusTools.Transcript

  @readme Path.expand("../../../../README.md", __DIR__)
  @docs Path.expand("../../../../docs", __DIR__)

  test "the README is a front door: under 350 lines, every doc linked, links inside the repository" do
    readme = File.read!(@readme)
    assert length(String.split(readme, "\n")) < 350

    links = Regex.scan(~r/\]\(([^)#\s]+)(?:#[^)]*)?\)/, readme, capture: :all_but_first)
    links = List.flatten(links)

    for doc <- Path.wildcard(Path.join(@docs, "*.md")) do
      assert "docs/#{Path.basename(doc)}" in links, "README does not link #{doc}"
    end

    for link <- links do
      refute link =~ ~r{^[a-z]+://}, "README links outside the repository: #{link}"
      assert File.exists?(Path.join(Path.dirname(@readme), link)), "README links #{link}, missing"
    end
  end

  test "every iex transcript of the README has examples" do
    examples = @readme |> File.read!() |> TartarusTools.Transcript.examples() |> List.flatten()
    assert length(examples) >= 10
    assert Enum.count(examples, & &1.expected) >= 10
  end

  @tag timeout: 120_000
  test "the README's iex transcripts give what they show, in a fresh VM" do
    ebins = :tartarus_tools |> :code.lib_dir() |> Path.join("../*/ebin") |> Path.wildcard()
    pa = Enum.flat_map(ebins, &["-pa", &1])

    script = """
    Logger.configure(level: :warning)
    {:ok, _} = Application.ensure_all_started(:tartarus_tools)
    TartarusTools.Transcript.check_file!(#{inspect(@readme)})
    IO.puts("transcripts: ok")
    """

    {out, status} =
      System.cmd(System.find_executable("elixir"), pa ++ ["-e", script], stderr_to_stdout: true)

    assert status == 0, out
    assert out =~ "transcripts: ok"
  end
end
