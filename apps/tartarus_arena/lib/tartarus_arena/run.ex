defmodule TartarusArena.Run do
  @moduledoc """
  Drives robots with path-following algorithms over the paths of `TartarusArena.Paths` and
  measures them: lap times, per-sub-path times and how well each robot stayed on the line.
  Pure: a world goes in, results and the final world come out.

  ## The measure of a sub-path run

  While a robot runs a PFA over a sub-path, each control step counts as *on the line* when
  the point between its two line sensors is within 3 cm of the line's centre (the tape is
  between or under the sensors). For one sub-path:

    * `time` - simulated seconds from entering the sub-path to leaving it;
    * `on_line` - the fraction of its steps on the line, 0..1;
    * `cost` - `time * (2 - on_line)` when completed (lower is better: a fast run that stays
      on the line costs its time; one that wandered off all the way costs twice its time);
      a run that timed out or lost the line costs `3 * max_time`.

  A robot is *lost* when its centre is more than 25 cm from the line, or when it rejoins
  the line more than 0.15 m further on than its progress (a shortcut, e.g. across a notch:
  `TartarusArena.Paths.track/4`'s `skipped`). In a single sub-path trial (`subpath/4`)
  that ends the trial (`completed: false`). When running laps (`laps/2`), as an
  experimenter would, it is put back on the line at the point of its progress, facing
  along it, and charged `lost_penalty` seconds (default 5) on its clock.

      iex> p = TartarusArena.Paths.path(1, 0)
      iex> r = TartarusArena.Run.subpath(TartarusArena.PFA.A4, p, 0, seed: 1)
      iex> r.completed and r.on_line > 0.9
      true
  """

  alias TartarusArena.{PFAs, Paths, World}

  @lost 0.25
  @on_line 0.03

  @typedoc "The measure of one run of a PFA over one sub-path."
  @type subpath_result :: %{
          path: 1 | 2,
          index: non_neg_integer(),
          type: Paths.type(),
          features: [float()],
          pfa: String.t(),
          completed: boolean(),
          time: float(),
          on_line: float(),
          cost: float()
        }

  @typedoc """
  A driver: which robot follows which path with which PFAs. `choose` is a PFA module (used
  everywhere) or a function of the sub-path (`t:TartarusArena.Paths.subpath/0`) returning
  one, called each time the robot enters a sub-path; without `choose`, the `:policy` option
  of `laps/3` chooses.
  """
  @type driver :: %{
          required(:robot) => World.id(),
          required(:path) => Paths.t(),
          optional(:choose) => module() | (Paths.subpath() -> module())
        }

  @typedoc """
  What a policy (the `:policy` option of `laps/3`) is told, with its state, and what it
  returns: `{:choose, robot, subpath}` -> `{pfa_module, state}` when a robot enters a
  sub-path; `{:result, robot, subpath_result}` -> `state` when it leaves one;
  `{:lap, robot, lap_number, seconds}` -> `state` when it completes a lap (before the
  result of the lap's last sub-path).
  """
  @type policy_event ::
          {:choose, World.id(), Paths.subpath()}
          | {:result, World.id(), subpath_result()}
          | {:lap, World.id(), pos_integer(), float()}

  @doc """
  Runs `pfa` over sub-path `index` of `path`, from the sub-path's start on the line
  (or from `:pose`), alone in a fresh arena with the path painted. Options: `:seed`
  (default 0), `:dt` (default 0.02 s), `:max_time` (default 4 x the sub-path's length at
  top speed, s), `:pose`, `:noise` (as `TartarusArena.World.new/1`), `:world` (more
  options of `TartarusArena.World.new/1`, e.g. `line_footprint: 0.015`), `:robot` (robot
  options, e.g. `accel: 0.5`). Returns the measure (see the moduledoc) with the sub-path's feature vector.
  """
  @spec subpath(module(), Paths.t(), non_neg_integer(), keyword()) :: subpath_result()
  def subpath(pfa, path, index, opts \\ []) do
    sp = Enum.at(path.subpaths, index)
    dt = Keyword.get(opts, :dt, 0.02)
    robot_opts = Keyword.get(opts, :robot, [])
    max_speed = Keyword.get(robot_opts, :max_speed, 0.25)
    max_time = Keyword.get(opts, :max_time, 4 * (sp.to - sp.from) / max_speed)
    {x, y, th} = Keyword.get_lazy(opts, :pose, fn -> Paths.point_at(path, sp.from + 0.001) end)

    world =
      World.new(
        [
          seed: {Keyword.get(opts, :seed, 0), path.id, index},
          noise: Keyword.get(opts, :noise, %{})
        ] ++ Keyword.get(opts, :world, [])
      )
      |> Paths.add_to(path)
      |> World.add_robot(:r, Keyword.merge(robot_opts, x: x, y: y, theta: th))

    tr = Paths.track_new(path, x, y)
    span = sp.to - sp.from
    state = pfa.init([])
    loop_subpath(world, pfa, state, path, tr, span, dt, max_time, 0, 0, sp)
  end

  defp loop_subpath(world, pfa, state, path, tr, span, dt, max_time, steps, on, sp) do
    t = World.time(world)

    cond do
      tr.progress >= span ->
        measure(path, sp, pfa, true, t, on / max(steps, 1), max_time)

      t >= max_time or tr.distance > @lost or tr.skipped ->
        measure(path, sp, pfa, false, t, on / max(steps, 1), max_time)

      true ->
        {readings, world} = World.sense(world, :r, [:line])
        {cmd, state} = pfa.control(readings.line, dt, state)
        on = on + if(sensor_mid_distance(world, :r, path, tr) <= @on_line, do: 1, else: 0)
        world = World.step(world, %{r: cmd}, dt)
        {x, y, _} = World.pose(world, :r)
        {tr, _} = Paths.track(tr, path, x, y)
        loop_subpath(world, pfa, state, path, tr, span, dt, max_time, steps + 1, on, sp)
    end
  end

  defp measure(path, sp, pfa, completed, t, on_line, max_time) do
    %{
      path: path.id,
      index: sp.index,
      type: sp.type,
      features: sp.features,
      pfa: PFAs.name(pfa),
      completed: completed,
      time: Float.round(t, 3),
      on_line: Float.round(on_line, 4),
      cost: Float.round(if(completed, do: t * (2 - on_line), else: 3.0 * max_time), 3)
    }
  end

  defp sensor_mid_distance(world, id, _path, _tr) do
    r = Map.fetch!(world.robots, id)
    World.line_distance(world, r.x + 0.06 * :math.cos(r.theta), r.y + 0.06 * :math.sin(r.theta))
  end

  @doc """
  Runs robots for laps on their paths, all in `world` at once (robots already added and
  placed). Options: `:laps` (default 1: stop when every robot has done this many),
  `:max_time` (default 600 s of simulated time), `:dt` (default 0.02 s), `:sample` (seconds
  between trajectory samples, default 0.1), `:lost_penalty` (default 5.0 s), `:stuck_after`
  (default 15.0 s: a robot that has not progressed 5 cm along its path for that long, e.g.
  spinning at a corner, is put 10 cm further on and charged the penalty, as an
  experimenter would nudge it). A robot that has done its laps stops and waits.

  `:policy` (a function of a `t:policy_event/0` and a state) and `:policy_state` (its
  initial state, default nil) let a learner choose each robot's PFA per sub-path and hear
  every sub-path's measure and every lap as they happen, in simulated-time order, one state
  shared by all robots (the selection experiment's hook: the learning itself is not here).
  The final state is returned as `policy_state`.

  Returns `%{world:, time:, robots: %{id => result}, policy_state:}` where each result has `lap_times`
  (seconds per completed lap, penalties included), `subpaths` (one
  `t:subpath_result/0` per sub-path crossed, in order, each with `put_back` and `nudged`,
  how often the robot was put back on the line or nudged on in it, and `penalty`, the
  seconds charged for that, included in its `time`), `trajectory` (`[{t, x, y}]`) and
  `lost` (how many times it was put back on the line or nudged on).
  """
  @spec laps([driver()], World.t() | keyword()) :: map()
  def laps(drivers, world, opts \\ []) do
    dt = Keyword.get(opts, :dt, 0.02)
    target = Keyword.get(opts, :laps, 1)
    max_time = Keyword.get(opts, :max_time, 600.0)
    sample = Keyword.get(opts, :sample, 0.1)
    penalty = Keyword.get(opts, :lost_penalty, 5.0)
    stuck = Keyword.get(opts, :stuck_after, 15.0)
    policy = Keyword.get(opts, :policy)

    {states, ps} =
      Enum.map_reduce(drivers, Keyword.get(opts, :policy_state), fn d, ps ->
        {x, y, _} = World.pose(world, d.robot)
        tr = Paths.track_new(d.path, x, y)
        sp = Paths.subpath_at(d.path, tr.s)
        {pfa, ps} = choose(d, sp, policy, ps)

        {{d.robot,
          %{
            driver: d,
            tr: tr,
            sp: sp,
            sp_end: sp.to - tr.start,
            base: 0.0,
            sp_t0: 0.0,
            sp_steps: 0,
            sp_on: 0,
            sp_lost: 0,
            sp_nudged: 0,
            sp_penalty: 0.0,
            pfa: pfa,
            ctl: pfa.init([]),
            penalty: 0.0,
            lap_t0: 0.0,
            lap_times: [],
            subpaths: [],
            trajectory: [{0.0, x, y}],
            lost: 0,
            best: 0.0,
            best_t: 0.0,
            next_sample: sample
          }}, ps}
      end)

    loop_laps(world, Map.new(states), ps, %{
      dt: dt,
      target: target,
      max_time: max_time,
      sample: sample,
      penalty: penalty,
      stuck: stuck,
      policy: policy
    })
  end

  defp choose(%{choose: f}, sp, _policy, ps) when is_function(f, 1), do: {f.(sp), ps}
  defp choose(%{choose: m}, _sp, _policy, ps) when is_atom(m), do: {m, ps}

  defp choose(d, sp, policy, ps) when is_function(policy, 2),
    do: policy.({:choose, d.robot, sp}, ps)

  defp notify(nil, _event, ps), do: ps
  defp notify(policy, event, ps), do: policy.(event, ps)

  defp loop_laps(world, states, ps, o) do
    t = World.time(world)

    if t >= o.max_time or Enum.all?(states, fn {_, s} -> length(s.lap_times) >= o.target end) do
      robots =
        Map.new(states, fn {id, s} ->
          {id,
           %{
             lap_times: Enum.reverse(s.lap_times),
             subpaths: Enum.reverse(s.subpaths),
             trajectory: Enum.reverse(s.trajectory),
             lost: s.lost
           }}
        end)

      %{world: world, time: t, robots: robots, policy_state: ps}
    else
      {cmds, world, states} =
        Enum.reduce(states, {%{}, world, states}, fn
          {id, s}, {cmds, world, states} when length(s.lap_times) >= o.target ->
            {Map.put(cmds, id, {0.0, 0.0}), world, states}

          {id, s}, {cmds, world, states} ->
            {readings, world} = World.sense(world, id, [:line])
            {cmd, ctl} = s.pfa.control(readings.line, o.dt, s.ctl)

            on =
              if sensor_mid_distance(world, id, s.driver.path, s.tr) <= @on_line, do: 1, else: 0

            s = %{s | ctl: ctl, sp_steps: s.sp_steps + 1, sp_on: s.sp_on + on}
            {Map.put(cmds, id, cmd), world, Map.put(states, id, s)}
        end)

      world = World.step(world, cmds, o.dt)
      t = World.time(world)

      {world, states, ps} =
        Enum.reduce(states, {world, states, ps}, fn
          {_id, s}, acc when length(s.lap_times) >= o.target ->
            acc

          {id, s}, {world, states, ps} ->
            {world, s, ps} = after_step(world, id, s, t, o, ps)
            {world, Map.put(states, id, s), ps}
        end)

      loop_laps(world, states, ps, o)
    end
  end

  defp after_step(world, id, s, t, o, ps) do
    path = s.driver.path
    {x, y, _} = World.pose(world, id)
    {tr, lap?} = Paths.track(s.tr, path, x, y)
    clock = t + s.penalty

    {best, best_t} =
      if tr.progress > s.best + 0.05, do: {tr.progress, t}, else: {s.best, s.best_t}

    s = %{s | best: best, best_t: best_t}

    {world, tr, s} =
      cond do
        # lost, or a shortcut: put back where its progress is (not at the nearest point,
        # which may be ahead of a lagging progress: the next step would count that as a
        # shortcut)
        tr.distance > @lost or tr.skipped ->
          {tr, pose} = Paths.back_to_progress(tr, path)
          world = World.place(world, id, pose)

          s = %{
            s
            | penalty: s.penalty + o.penalty,
              lost: s.lost + 1,
              sp_lost: s.sp_lost + 1,
              sp_penalty: s.sp_penalty + o.penalty
          }

          {world, tr, s}

        t - best_t > o.stuck ->
          {tr, _} = Paths.back_to_progress(tr, path)
          world = World.place(world, id, Paths.point_at(path, tr.start + tr.progress + 0.1))

          s = %{
            s
            | penalty: s.penalty + o.penalty,
              lost: s.lost + 1,
              best_t: t,
              sp_nudged: s.sp_nudged + 1,
              sp_penalty: s.sp_penalty + o.penalty
          }

          {world, tr, s}

        true ->
          {world, tr, s}
      end

    s = %{s | tr: tr}

    # a lap, then the end of a sub-path (the last one of a lap ends with it) go to the
    # policy, before the next sub-path's PFA is chosen
    {s, ps} =
      if lap? do
        secs = Float.round(clock - s.lap_t0, 3)
        ps = notify(o.policy, {:lap, id, length(s.lap_times) + 1, secs}, ps)
        {%{s | lap_times: [secs | s.lap_times], lap_t0: clock}, ps}
      else
        {s, ps}
      end

    {s, ps} =
      if tr.progress >= s.sp_end - 1.0e-9 do
        r =
          measure(path, s.sp, s.pfa, true, clock - s.sp_t0, s.sp_on / max(s.sp_steps, 1), 0.0)
          |> Map.merge(%{
            put_back: s.sp_lost,
            nudged: s.sp_nudged,
            penalty: Float.round(s.sp_penalty, 3)
          })

        ps = notify(o.policy, {:result, id, r}, ps)

        next = Enum.at(path.subpaths, rem(s.sp.index + 1, length(path.subpaths)))
        base = if next.index == 0, do: s.base + path.length, else: s.base
        {pfa, ps} = choose(s.driver, next, o.policy, ps)

        {%{
           s
           | subpaths: [r | s.subpaths],
             sp: next,
             sp_end: base + next.to - tr.start,
             base: base,
             sp_t0: clock,
             sp_steps: 0,
             sp_on: 0,
             sp_lost: 0,
             sp_nudged: 0,
             sp_penalty: 0.0,
             pfa: pfa,
             ctl: if(pfa == s.pfa, do: s.ctl, else: pfa.init([]))
         }, ps}
      else
        {s, ps}
      end

    s =
      if t >= s.next_sample - 1.0e-9,
        do: %{
          s
          | trajectory: [{Float.round(t, 3), x, y} | s.trajectory],
            next_sample: s.next_sample + o.sample
        },
        else: s

    {world, s, ps}
  end

  @doc """
  A world with both paths painted and robots placed on their flags: `robots` is a list of
  `{id, path, offset}` (offset: arc length from the flag, m). Options as
  `TartarusArena.World.new/1`.
  """
  @spec arena([{World.id(), Paths.t(), number()}], keyword()) :: World.t()
  def arena(robots, opts \\ []) do
    paths = robots |> Enum.map(&elem(&1, 1)) |> Enum.uniq_by(& &1.id)
    world = Enum.reduce(paths, World.new(opts), &Paths.add_to(&2, &1))

    Enum.reduce(robots, world, fn {id, path, offset}, world ->
      {x, y, th} = Paths.point_at(path, offset + 0.001)
      World.add_robot(world, id, x: x, y: y, theta: th)
    end)
  end
end
