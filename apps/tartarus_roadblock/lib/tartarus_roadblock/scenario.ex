defmodule TartarusRoadblock.Scenario do
  @moduledoc """
  The roadblock scenario of thesis §2.4 as a `TartarusEmu.Scenario` (run it with
  `TartarusRoadblock.run/1`; options in `TartarusRoadblock.schema/0`).

  Setup starts the arena (`TartarusRoadblock.Site.world/1`) and a 13-node
  `TartarusEmu.Network` (`TartarusRoadblock.Site.topology/0`, virtual or peer mode) whose
  per-node setup hook attaches the devices and creates the static agents: Santa's devices
  and its controller (`TartarusRoadblock.Commuter`) on `pc1`, the webcam and
  `TartarusRoadblock.Monitor` on the Pi, `TartarusRoadblock.Admin` on `pc7`, Rudolph's and
  Claus's devices on `pc10` and `pc11`.

  Each step is one control period of 0.05 s of arena time: the block appears (at
  `block_at` seconds), Santa's controller and, once installed, the rescue program each get
  a `:tick` request, then the arena steps. The world stands still while the network
  works (the report, the snapshot, the administrator, the rescue agent's walk), so the
  same seed gives the same run in either mode; the timeline records both the arena's time
  and the wall clock (the machine's, `Tartarus.Clock.machine_time/1`).
  """
  @behaviour TartarusEmu.Scenario

  alias Tartarus.Clock
  alias TartarusArena.{Server, World}
  alias TartarusEmu.Network
  alias TartarusRoadblock.{Admin, Commuter, Monitor, Rescuer}

  require Tartarus.Clock

  @dt 0.05
  @driver TartarusRoadblock.Driver

  @impl true
  @doc false
  def name, do: "roadblock"

  @impl true
  @doc false
  def title, do: "Roadblock rescue (thesis §2.4)"

  @impl true
  @doc false
  def setup(opts) do
    {world, layout} = TartarusRoadblock.Site.world(opts.seed)
    {:ok, arena} = Server.start_link(world: world, dt: @dt)
    me = self()

    setup = fn n, host, net -> setup_node(n, host, net, arena, layout, me) end

    case Network.start(TartarusRoadblock.Site.topology(),
           mode: opts[:mode] || :virtual,
           setup: setup
         ) do
      {:ok, net} ->
        auto = Map.get(opts, :auto, true)
        unless auto, do: Process.register(self(), @driver)

        {:ok,
         %{
           net: net,
           arena: arena,
           layout: layout,
           auto: auto,
           requirement: opts[:requirement] || [:drive, :claws],
           block_at: opts[:block_at] || 1.5,
           mode: opts[:mode] || :virtual,
           seed: opts.seed,
           phase: :driving,
           t: 0.0,
           t0: Clock.machine_time(:millisecond),
           block_placed: false,
           santa: %{phase: :driving},
           santa_host: Network.host(net, :pc1),
           admin_host: Network.host(net, :pc7),
           rescuer: nil,
           program_phase: nil,
           chosen: nil,
           chosen_host: nil,
           candidates: [],
           hops: 0,
           visited: 0,
           result: nil,
           snapshot: nil,
           report: nil,
           timeline: [],
           trajs: %{santa: [], claus: [], rudolph: []},
           series: TartarusTools.Series.new(),
           santa_arrived_at: nil,
           rescue_done_at: nil,
           santa_stopped_s: 0.0,
           released_ms: nil,
           installed_ms: nil,
           paused_ms: nil,
           # read by the dashboard's panel (TartarusRoadblock.Panel)
           status: :ets.new(:roadblock_status, [:public, :set, read_concurrency: true])
         }
         |> event(:santa, "santa", "drives from A")}

      {:error, _} = error ->
        GenServer.stop(arena)
        error
    end
  end

  defp setup_node(n, host, net, arena, layout, me) do
    robot = fn name, id, devices ->
      :ok =
        Tartarus.attach_plugin(host, :robot, {TartarusArena.RobotPlugin, arena: arena, robot: id})

      for {plugin, device} <- devices do
        :ok =
          Tartarus.attach_plugin(
            host,
            plugin,
            {TartarusArena.DevicePlugin, arena: arena, robot: id, device: device}
          )
      end

      Tartarus.store_put(host, :robot, name)
    end

    case n do
      :pc1 ->
        robot.("santa", :santa,
          sonar: :ultrasonic,
          colour: :colour,
          light: :light,
          line: :line,
          motors: :motors
        )

        Tartarus.create_static_agent(
          host,
          Commuter,
          %{monitor: {"monitor", Network.host(net, :pi)}, dest_x: layout.dest_x},
          name: "santa"
        )

      :pc10 ->
        robot.("rudolph", :rudolph, sonar: :ultrasonic, motors: :motors)

      :pc11 ->
        robot.("claus", :claus, sonar: :ultrasonic, motors: :motors)

      :pi ->
        :ok =
          Tartarus.attach_plugin(
            host,
            :camera,
            {TartarusArena.CameraPlugin,
             arena: arena, pose: layout.camera, pixels: {320, 240}, capabilities: [:camera]}
          )

        Tartarus.create_static_agent(
          host,
          Monitor,
          %{admin: {"admin", Network.host(net, :pc7)}},
          name: "monitor"
        )

      :pc7 ->
        Tartarus.create_static_agent(host, Admin, %{watcher: me}, name: "admin")

      _ ->
        :ok
    end
  end

  @impl true
  @doc false
  def step(s, step) do
    s = %{s | t: Float.round(step * @dt, 2)}
    s = maybe_place_block(s)
    s = tick_santa(s)
    s = if s.phase == :rescue, do: tick_rescuer(s), else: s
    :ok = Server.step(s.arena, 1)
    s |> record(step) |> publish()
  end

  @impl true
  @doc false
  def panels(s), do: [{TartarusRoadblock.Panel, s.status}]

  # What the dashboard's panel shows (it reads the table, never this loop).
  defp publish(s, waiting \\ false) do
    w = Server.world(s.arena)
    {sx, _, _} = World.pose(w, :santa)

    :ets.insert(
      s.status,
      {:status,
       %{
         t: s.t,
         phase: s.phase,
         santa_phase: s.santa.phase,
         santa_x: Float.round(sx, 2),
         block: if(s.block_placed, do: "x = #{Float.round(elem(s.layout.block, 0), 2)} m"),
         chosen: s.chosen,
         program_phase: s.program_phase,
         hops: s.hops,
         visited: s.visited,
         waiting: waiting,
         auto: s.auto,
         events: s.timeline |> Enum.take(5),
         snapshot: s.snapshot
       }}
    )

    s
  end

  defp maybe_place_block(%{block_placed: false, t: t} = s) when t >= s.block_at do
    {bx, by} = s.layout.block

    Server.update(
      s.arena,
      &World.add_puck(&1, :block, x: bx, y: by, radius: 0.04, colour: 2, tall: true)
    )

    event(%{s | block_placed: true}, :block, "block", "appears at x=#{Float.round(bx, 2)}")
  end

  defp maybe_place_block(s), do: s

  defp tick_santa(s) do
    {:ok, r} = Tartarus.request({"santa", s.santa_host}, :tick, 10_000)

    s =
      cond do
        r.phase != s.santa.phase and r.phase == :arrived ->
          event(%{s | santa_arrived_at: s.t}, :santa, "santa", "arrives at B")

        r.phase != s.santa.phase and r.phase == :stopped ->
          event(s, :santa, "santa", "stops: obstacle at #{r.ultrasonic} cm")

        r.phase != s.santa.phase and r.phase == :driving ->
          event(s, :santa, "santa", "drives on")

        true ->
          s
      end

    s = %{s | santa: r}
    s = if r.phase == :stopped, do: %{s | santa_stopped_s: s.santa_stopped_s + @dt}, else: s
    if r.reported, do: handle_report(s), else: s
  end

  # Santa told the monitoring node; the world stands still while the network works.
  defp handle_report(s) do
    s = %{s | paused_ms: now(s)}

    {png, report} =
      Clock.receive do
        {:roadblock_snapshot, png, report} -> {png, report}
      after
        30_000 -> raise "roadblock: no snapshot reached the administrator within 30 s"
      end

    s =
      %{s | snapshot: png, report: report, phase: :admin}
      |> event(:network, "monitor", "snapshot taken (#{byte_size(png)} bytes PNG)")
      |> event(:network, "admin", "snapshot received")

    {requirement, reply_to} =
      if s.auto do
        {s.requirement, nil}
      else
        IO.puts("""
        roadblock: Santa is blocked at #{inspect(round2(report.block))}; the monitoring node's \
        snapshot (#{byte_size(png)} bytes) is at the administrator's host.
        Look at it with TartarusRoadblock.snapshot("snapshot.png"), then release the rescue agent:
            TartarusRoadblock.release_rescue()
        """)

        publish(s, true)
        await_administrator(s)
      end

    release(%{s | requirement: requirement}, reply_to)
  end

  defp await_administrator(s) do
    receive do
      {:roadblock_release, from, ref, opts} ->
        {Keyword.get(opts, :requirement, s.requirement), {from, ref}}

      {:roadblock_snapshot_request, from, ref} ->
        send(from, {ref, {s.snapshot, s.report}})
        await_administrator(s)
    end
  end

  defp release(s, reply_to) do
    s =
      %{s | released_ms: now(s)}
      |> event(:network, "admin", "releases the rescue agent")
      |> publish()

    {:ok, id} =
      Tartarus.create_mobile_agent(
        s.admin_host,
        Rescuer,
        %{requirement: s.requirement, block: s.report.block, watcher: self()},
        owner: self(),
        name: "rescuer"
      )

    if reply_to, do: send(elem(reply_to, 0), {elem(reply_to, 1), {:ok, id}})
    await_install(%{s | rescuer: id})
  end

  defp await_install(s) do
    Clock.receive do
      {:roadblock_visit, host, robot, caps} ->
        what = if robot, do: "#{robot}: #{Enum.join(caps, ", ")}", else: "no robot"

        s =
          event(
            %{s | visited: s.visited + 1},
            :network,
            "rescuer",
            "visits #{host_name(s, host)} (#{what})"
          )

        await_install(publish(s))

      {:roadblock_chosen, robot, host, candidates} ->
        s = %{s | chosen: robot, chosen_host: host, candidates: candidates}
        await_install(publish(event(s, :network, "rescuer", "chooses #{robot}")))

      {:roadblock_installed, robot, host, hops} ->
        s = %{s | phase: :rescue, hops: hops, rescuer: {s.rescuer, host}, installed_ms: now(s)}
        event(s, :network, "rescuer", "installs the rescue program on #{robot} (#{hops} hops)")

      {:tartarus_result, _id, result} ->
        raise "roadblock: the rescue agent found no robot: #{inspect(result)}"
    after
      60_000 -> raise "roadblock: the rescue agent did not install its program within 60 s"
    end
  end

  defp tick_rescuer(s) do
    {:ok, r} = Tartarus.request(s.rescuer, :tick, 10_000)

    s =
      if r.phase != s.program_phase,
        do: event(%{s | program_phase: r.phase}, :rescue, s.chosen, phase_text(r.phase)),
        else: s

    if r.phase == :done do
      result =
        Clock.receive do
          {:tartarus_result, _, result} -> result
        after
          10_000 -> raise "roadblock: the rescue agent did not return"
        end

      %{s | phase: :done, result: result, hops: result.hops, rescue_done_at: s.t}
    else
      s
    end
  end

  defp phase_text(:to_block), do: "drives to the block"
  defp phase_text(:face), do: "turns to the block"
  defp phase_text(:approach), do: "approaches the block"
  defp phase_text(:carry), do: "grips the block, carries it off the path"
  defp phase_text(:release), do: "puts the block down"
  defp phase_text(:back_off), do: "backs off"
  defp phase_text(:home), do: "drives back to the dock"
  defp phase_text(:dock), do: "turns into its dock"
  defp phase_text(:done), do: "docked"
  defp phase_text(p), do: to_string(p)

  defp record(s, step) do
    w = Server.world(s.arena)

    trajs =
      Map.new(s.trajs, fn {id, pts} ->
        {x, y, _} = World.pose(w, id)
        {id, [{s.t, x, y} | pts]}
      end)

    {sx, _, _} = World.pose(w, :santa)
    {cx, cy, _} = World.pose(w, :claus)

    series = TartarusTools.Series.record(s.series, :santa_x, step, Float.round(sx, 3))

    series =
      case block_distance(w, cx, cy) do
        nil -> series
        d -> TartarusTools.Series.record(series, :claus_to_block, step, d)
      end

    %{s | trajs: trajs, series: series}
  end

  defp block_distance(w, x, y) do
    case Map.get(w.pucks, :block) do
      nil -> nil
      p -> Float.round(:math.sqrt((p.x - x) ** 2 + (p.y - y) ** 2), 3)
    end
  end

  @impl true
  @doc false
  def done?(s, _step), do: s.santa_arrived_at != nil and s.phase == :done

  @impl true
  @doc false
  def series(s), do: s.series

  @impl true
  @doc false
  def summary(s) do
    w = Server.world(s.arena)
    block = Map.get(w.pucks, :block)
    {_, line_y} = s.layout.block

    off_path = block != nil and block.held_by == nil and abs(block.y - line_y) > 0.15

    {cx, cy, _} = World.pose(w, :claus)
    {dx, dy, _} = s.layout.docks.claus

    %{
      rescued: off_path and s.result != nil,
      chosen_robot: s.chosen,
      santa_arrived: s.santa_arrived_at != nil,
      agent_hops: s.hops,
      seconds: s.t,
      santa_arrival_s: s.santa_arrived_at,
      santa_stopped_s: Float.round(s.santa_stopped_s, 2),
      rescue_done_s: s.rescue_done_at,
      claus_docked: s.result != nil and :math.sqrt((cx - dx) ** 2 + (cy - dy) ** 2) < 0.05,
      block: %{x: Float.round(elem(s.layout.block, 0), 3), y: line_y},
      block_final: block && %{x: Float.round(block.x, 3), y: Float.round(block.y, 3)},
      candidates: Enum.map(s.candidates, &%{robot: &1.robot, capabilities: &1.capabilities}),
      requirement: s.requirement,
      hosts_visited: s.visited,
      nodes: 13,
      mode: s.mode,
      snapshot_bytes: s.snapshot && byte_size(s.snapshot),
      release_to_install_ms: s.installed_ms && s.released_ms && s.installed_ms - s.released_ms,
      timeline_events: length(s.timeline)
    }
  end

  @impl true
  @doc false
  def write(s, dir) do
    w = Server.world(s.arena)
    png = Path.join(dir, "snapshot.png")
    if s.snapshot, do: File.write!(png, s.snapshot)

    trajs = Map.new(s.trajs, fn {id, pts} -> {id, Enum.reverse(pts)} end)

    svg =
      TartarusTools.SVG.write!(
        Path.join(dir, "trajectories.svg"),
        TartarusArena.Render.trajectories(w, trajs,
          title: "Roadblock: the robots' paths",
          subtitle:
            "block placed at #{s.block_at} s, rescue needs #{Enum.join(s.requirement, " + ")}, " <>
              "#{s.mode} mode, seed #{s.seed}"
        )
      )

    events = Enum.reverse(s.timeline)
    csv = Path.join(dir, "timeline.csv")

    File.write!(csv, [
      "arena_s,wall_ms,lane,actor,event\n"
      | Enum.map(events, fn e ->
          "#{e.t},#{e.wall_ms},#{e.lane},#{e.actor},\"#{String.replace(e.text, "\"", "'")}\"\n"
        end)
    ])

    timeline = TartarusTools.SVG.write!(Path.join(dir, "timeline.svg"), timeline_svg(events, s))
    Enum.filter([png, svg, csv, timeline], &File.exists?/1)
  end

  # One lane per actor; each event opens a span that lasts until the actor's next event
  # (or the end). The x axis is the arena's time with the network's pause spliced in: while
  # the arena stood still (from Santa's report to the program's installation) time goes on
  # by the wall clock.
  defp timeline_svg(events, s) do
    x = fn e -> Float.round(e.t + pause_s(e.wall_ms, s), 3) end
    last = x.(List.last(events) || %{t: s.t, wall_ms: now(s)}) + 0.2

    rows =
      events
      |> Enum.group_by(& &1.actor)
      |> Enum.sort_by(fn {_, evs} -> hd(evs).wall_ms end)
      |> Enum.map(fn {actor, evs} ->
        final = List.last(evs)

        stops =
          Enum.map(tl(evs), x) ++ [if(final.lane == :network, do: x.(final) + 0.3, else: last)]

        spans =
          Enum.zip_with(evs, stops, fn e, stop ->
            %{start: x.(e), stop: max(stop, x.(e) + 0.01), label: e.text, group: e.lane}
          end)

        %{label: to_string(actor), spans: spans}
      end)

    TartarusTools.SVG.gantt(rows,
      title: "Roadblock rescue: who does what",
      x_label:
        "arena seconds (the network's work, while the arena stands still, on the wall clock)"
    )
  end

  defp pause_s(_wall_ms, %{paused_ms: nil}), do: 0.0

  defp pause_s(wall_ms, s) do
    len = (s.installed_ms || now(s)) - s.paused_ms
    min(max(wall_ms - s.paused_ms, 0), len) / 1000
  end

  @impl true
  @doc false
  def teardown(s) do
    if Process.whereis(@driver) == self(), do: Process.unregister(@driver)
    Network.stop(s.net)
    if Process.alive?(s.arena), do: GenServer.stop(s.arena)
  end

  defp event(s, lane, actor, text) do
    e = %{t: s.t, wall_ms: now(s), lane: lane, actor: actor, text: text}
    %{s | timeline: [e | s.timeline]}
  end

  # The wall clock's ms since the setup (the timeline's `wall_ms`: the machine's time).
  defp now(s), do: Clock.machine_time(:millisecond) - s.t0

  defp host_name(s, host) do
    case Network.topo_node(s.net, host) do
      nil -> inspect(host)
      n -> to_string(n)
    end
  end

  defp round2({x, y}), do: {Float.round(x, 2), Float.round(y, 2)}
end
