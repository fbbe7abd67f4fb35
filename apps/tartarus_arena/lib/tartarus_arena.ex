defmodule TartarusArena do
  @moduledoc """
  A 2-D robot arena: the physical world of the thesis's robot experiments, simulated.

  The pieces:

    * `TartarusArena.World` - the pure simulator: `step(world, commands, dt)` integrates
      differential-drive robots (wheel limits and noise from a seeded stream), collisions
      with walls, pucks and each other, pucks pushed or held by a gripper, a switchable
      light, floor lines and coloured markers; `sense(world, robot)` reads the ultrasonic,
      colour, two light and two line sensors with the thesis's ranges. Units: metres,
      seconds, radians; readings as the NXT's.
    * `TartarusArena.Paths` - the two closed paths of §6.5.11 with their sub-paths (sp-a
      curved, sp-b 90° turns, sp-c straight, sp-d acute turns), Table 6.3's features,
      start/finish flags and lap tracking.
    * `TartarusArena.PFA` - the eight path-following algorithms of Table 6.4 (A1-A8), each
      a self-contained module an agent can carry.
    * `TartarusArena.Run` - drives robots with PFAs: one PFA over one sub-path (time,
      staying on the line, cost, features: the building block of the selection
      experiment) and laps of several robots at once.
    * `TartarusArena.Server`, `TartarusArena.RobotPlugin`, `TartarusArena.CameraPlugin` -
      one process owns a shared world; robot hosts reach their robot, and a monitoring
      node its camera, through the platform's plugin channel.
    * `TartarusArena.Render`, `TartarusArena.PNG` - SVG snapshots and trajectory plots, and
      PNG camera snapshots.

  `docs/arena.md` is the guide, with the figures.
  """

  @doc """
  A world with both paths of §6.5.11 painted (`TartarusArena.Paths.path/2` with `seed`)
  and no robot. Options as `TartarusArena.World.new/1` (`seed` is used for both).

      iex> w = TartarusArena.paths_world(1)
      iex> length(w.lines)
      2
  """
  @spec paths_world(term(), keyword()) :: TartarusArena.World.t()
  def paths_world(seed, opts \\ []) do
    world = TartarusArena.World.new(Keyword.put(opts, :seed, seed))

    Enum.reduce(
      [1, 2],
      world,
      &TartarusArena.Paths.add_to(&2, TartarusArena.Paths.path(&1, seed))
    )
  end
end
