# Keeps the lab off the devices: the release's applications (mix.exs, release_apps/0, as
# built by default) and the firmware's path dependencies (firmware/mix.exs), with every
# application they need, must hold no emulator, tooling or experiment application, and no
# module of theirs may call one (the imports of their compiled modules). Run by
# scripts/check-layers after compiling:
#
#   mix run --no-start --no-compile scripts/check-closure.exs
#   mix run --no-start --no-compile scripts/check-closure.exs --release-apps tartarus_node,tartarus_lats
#
# (--release-apps / --firmware-apps replace the lists, e.g. to see the check fail.)
# Exits 1, naming each offence, when the rule is broken.
defmodule CheckClosure do
  # The lab: the emulator, the tooling (benchmarks, chaos, SVG, the dashboard) and the
  # applications' experiments.
  @lab_apps [
    :tartarus_emu,
    :tartarus_tools,
    :tartarus_lats,
    :tartarus_arena,
    :tartarus_immune,
    :tartarus_roadblock,
    :tartarus_warehouse
  ]
  @lab_modules ~r/^Elixir\.(TartarusEmu|TartarusTools)(\.|$)/

  def main(args) do
    {opts, _, _} =
      OptionParser.parse(args, strict: [release_apps: :string, firmware_apps: :string])

    sets = [
      {"the release", list(opts[:release_apps]) || release_apps()},
      {"the firmware", list(opts[:firmware_apps]) || firmware_apps()}
    ]

    offences = for {what, apps} <- sets, offence <- offences(apps), do: "#{what}: #{offence}"

    if offences == [] do
      IO.puts(
        "check-closure: " <>
          Enum.map_join(sets, "; ", fn {what, apps} ->
            "#{what} (#{Enum.join(closure(apps), ", ")}) holds no lab application or call"
          end)
      )
    else
      Enum.each(offences, &IO.puts(:stderr, &1))
      IO.puts(:stderr, "check-closure: the lab is in a device's dependency closure (above)")
      System.halt(1)
    end
  end

  defp list(nil), do: nil
  defp list(text), do: text |> String.split(",", trim: true) |> Enum.map(&String.to_atom/1)

  defp release_apps do
    Mix.Project.config()[:releases][:tartarus][:applications] |> Keyword.keys()
  end

  defp firmware_apps do
    text = File.read!("firmware/mix.exs")

    for [_, app] <- Regex.scan(~r/\{:(\w+),\s*path:\s*"\.\.\/apps\//, text),
        do: String.to_atom(app)
  end

  # The applications `apps` need, themselves included, as their .app files say.
  defp closure(apps), do: apps |> Enum.reduce([], &add/2) |> Enum.sort()

  defp add(app, seen) do
    if app in seen do
      seen
    else
      case Application.load(app) do
        r when r == :ok or elem(r, 1) == {:already_loaded, app} -> :ok
        {:error, reason} -> raise "cannot load #{app}: #{inspect(reason)}"
      end

      Enum.reduce(Application.spec(app, :applications) || [], [app | seen], &add/2)
    end
  end

  defp offences(apps) do
    closure = closure(apps)
    # Calls from the device code itself (the lab's own calls add nothing to the offence).
    ours =
      Enum.filter(
        closure,
        &(String.starts_with?(Atom.to_string(&1), "tartarus") and &1 not in @lab_apps)
      )

    in_closure = for app <- closure, app in @lab_apps, do: "application #{app} is in it"

    calls =
      for app <- ours,
          module <- Application.spec(app, :modules) || [],
          not test_support?(module),
          lab <- lab_calls(module) do
        "#{inspect(module)} (#{app}) calls #{inspect(lab)}"
      end

    in_closure ++ Enum.uniq(calls)
  end

  # A test build compiles test/support into its app (MIX_ENV=test); no device runs those.
  defp test_support?(module) do
    Code.ensure_loaded(module)
    source = to_string(module.module_info(:compile)[:source])
    String.contains?(source, "/test/support/")
  end

  defp lab_calls(module) do
    with file when is_list(file) <- :code.which(module),
         {:ok, {_, [imports: imports]}} <- :beam_lib.chunks(file, [:imports]) do
      imports
      |> Enum.map(&elem(&1, 0))
      |> Enum.filter(&(Atom.to_string(&1) =~ @lab_modules))
      |> Enum.uniq()
    else
      _ -> []
    end
  end
end

CheckClosure.main(System.argv())
