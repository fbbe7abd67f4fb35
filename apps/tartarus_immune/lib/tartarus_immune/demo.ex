defmodule TartarusImmune.Demo do
  @moduledoc false
  # The immune selection's part of `mix tartarus.demo`: P3 and P1 on a 10-host grid.
  @behaviour TartarusTools.Demo
  import TartarusTools.Demo, only: [say: 1]

  @impl true
  def title, do: "Immune selection: iPkts find the best sorting algorithm per kind of sequence"

  @impl true
  def run(opts) do
    seed = opts[:seed] || 1

    for set <- [:p3, :p1] do
      {:ok, r} =
        TartarusEmu.Scenario.run(TartarusImmune.Experiment,
          set: set,
          seed: seed,
          nodes: 10,
          steps: 200,
          quiet: true,
          out: if(opts[:out], do: Path.join(opts[:out], "immune-#{set}"), else: false)
        )

      s = r.summary

      say(
        "#{set}: #{s.winner} took over at step #{s.convergence_step || "-"} (known best #{s.known_best}); " <>
          "#{s.migrations} iPkt moves, #{s.clones} clones, #{s.deaths} deaths; " <>
          "held-out accuracy #{Float.round(s.test_accuracy * 1.0, 2)}"
      )
    end

    :ok
  end
end
