defmodule TartarusRoadblock.Demo do
  @moduledoc false
  # The roadblock's part of `mix tartarus.demo`: one run in auto mode, virtual hosts.
  @behaviour TartarusTools.Demo
  import TartarusTools.Demo, only: [say: 1]

  @impl true
  def title, do: "Roadblock: a mobile agent chooses a rescue robot and programs it (thesis §2.4)"

  @impl true
  def run(opts) do
    {:ok, %{summary: s}} = TartarusRoadblock.run(seed: opts[:seed] || 1, out: false)

    say(
      "Santa blocked; webcam snapshot (#{s.snapshot_bytes} bytes PNG) sent to the administrator, who released the rescue agent"
    )

    say(
      "the agent visited #{s.hosts_visited} hosts, compared #{Enum.map_join(s.candidates, ", ", & &1.robot)} against #{inspect(s.requirement)}, chose #{s.chosen_robot} (#{s.agent_hops} hops)"
    )

    say(
      "rescued: #{s.rescued}; Santa arrived: #{s.santa_arrived} at #{s.santa_arrival_s} s (arena time); #{s.chosen_robot} back at its dock: #{s.claus_docked}"
    )

    :ok
  end
end
