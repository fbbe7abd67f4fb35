defmodule Mix.Tasks.Tartarus.Demo do
  @shortdoc "Runs the demo: the platform and every scenario, briefly"

  @schema [
    seed: [type: :pos_integer, default: 1, doc: "seed of every random choice"],
    out: [type: :string, default: "results/demo", doc: "directory of the scenarios' reports"],
    only: [
      type: :string,
      doc:
        "run only the sections whose title starts with this (any case: `platform`, " <>
          "`emulation`, `lats`, ...); an unknown name is refused with the list"
    ]
  ]

  @moduledoc """
  The README's first command: a short tour of the platform and of each application.

      mix tartarus.demo [--seed N] [--out DIR] [--only TITLE_PREFIX]

  It starts real BEAM nodes on this machine, so `epmd` must be available (it comes with
  Erlang/OTP). Sections come from `TartarusTools.Demo.sections/0`; scenario sections write their
  reports under `--out`.

  Options (flags are the keys with dashes):

  #{TartarusTools.CLI.flag_docs(@schema)}
  """
  use TartarusTools.CLI

  @impl true
  def run(argv) do
    opts = TartarusTools.CLI.options!(argv, @schema, "tartarus.demo")
    Mix.Task.run("app.start")
    Logger.configure(level: :warning)

    for section <- sections!(opts[:only]) do
      IO.puts("\n== #{section.title()}")
      t0 = Tartarus.Clock.machine_time(:millisecond)

      case section.run(opts) do
        :ok -> IO.puts("  (#{Tartarus.Clock.machine_time(:millisecond) - t0} ms)")
        {:error, reason} -> TartarusTools.CLI.error!("tartarus.demo", "section failed: #{inspect(reason)}")
      end
    end
  end

  # The sections `--only` names: those whose name (the title before its colon) or title
  # starts with it, whatever the case; none is an error that lists the names.
  defp sections!(nil), do: TartarusTools.Demo.sections()

  defp sections!(only) do
    sections = TartarusTools.Demo.sections()
    prefix = String.downcase(String.trim(only))

    case Enum.filter(sections, &String.starts_with?(String.downcase(&1.title()), prefix)) do
      [_ | _] = chosen when prefix != "" ->
        chosen

      _ ->
        names = Enum.map_join(sections, ", ", &name/1)

        Mix.raise(
          "mix tartarus.demo: --only #{inspect(only)} names no section; the sections are: #{names}"
        )
    end
  end

  defp name(section), do: section.title() |> String.split(":") |> hd() |> String.downcase()
end
