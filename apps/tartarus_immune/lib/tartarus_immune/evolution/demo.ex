defmodule TartarusImmune.Evolution.Demo do
  @moduledoc false
  # Embodied evolution's part of `mix tartarus.demo`: one robot learning S3 on the arena
  # (antibodies for light on and off), and the OR-gate sharing experiment on 20 nodes.
  @behaviour TartarusTools.Demo
  import TartarusTools.Demo, only: [say: 1]

  alias TartarusImmune.Evolution.{Embodied, Sharing}

  @impl true
  def title,
    do: "Embodied evolution: antibody repertoires on the arena, shared by broadcast or by iPkts"

  @impl true
  def run(opts) do
    seed = opts[:seed] || 1
    {:ok, r} = Embodied.run(scenario: :s3, seed: seed, test_episodes: 2)
    [on, off] = r.light_switches

    say(
      "S3, one robot, 500 iterations (light on at #{on}, off again at #{off}): #{r.antibodies} antibodies, " <>
        "#{r.by_light.on} used with the light on, #{r.by_light.off} with it off; " <>
        "#{r.reused_after_return} of the first dark phase's selected again when the light went off again"
    )

    for scheme <- [:broadcast, :ipkt] do
      {:ok, s} = Sharing.run(nodes: 20, scheme: scheme, ipkts: 2, seed: seed)

      say(
        "OR gate on 20 dynamic nodes, #{if scheme == :ipkt, do: "2 iPkts", else: "broadcast"}: " <>
          "90 % solved #{s.omega} iterations after the first, #{s.gamma_avg} messages per node"
      )
    end

    :ok
  end
end
