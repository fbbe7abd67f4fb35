defmodule TartarusEmu.Demo do
  @moduledoc false
  # The emulator's part of `mix tartarus.demo`: conscientious agents exploring a grid whose
  # nodes break off and reconnect, with the report written to disk.
  @behaviour TartarusTools.Demo
  import TartarusTools.Demo, only: [say: 1]

  @impl true
  def title, do: "Emulation: agents exploring a 6x6 grid whose nodes come and go"

  @impl true
  def run(opts) do
    out = Path.expand(Path.join(opts[:out], "emu"))

    run_opts = [
      topology: "grid",
      hosts: 36,
      agents: 6,
      steps: 120,
      strategy: :conscientious,
      p: 0.02,
      seed: opts[:seed],
      out: out,
      quiet: true
    ]

    case TartarusEmu.Walk.run(run_opts) do
      {:ok, s} ->
        say(
          "#{s.hosts} hosts, #{s.agents} conscientious agents, p = #{s.p} per step: coverage #{Float.round(s.coverage * 1.0, 2)} (complete at step #{inspect(s.covered_at_step)})"
        )

        say(
          "#{s.migrations} migrations, #{s.failed_moves} failed on broken links, #{s.bytes} bytes, #{s.energy_mj} mJ"
        )

        say("report: #{out}/summary.md, plots: #{out}/coverage.svg, #{out}/walk.svg")
        :ok

      {:error, reason} ->
        {:error, reason}
    end
  end
end
