defmodule TartarusWarehouse.Robot do
  @moduledoc """
  A robot, as a plugin of its host (`Tartarus.Plugin`): its state (thesis §4.3: `:free`
  for S1*, or the state a booked robot waits in), the resources it reaches, and the
  execution of the task programs agents bring. Attach it under the name `:robot`:

      Tartarus.attach_plugin(host, :robot, {TartarusWarehouse.Robot, robot: "r1", scale: 0.01})

  ## Options

    * `:robot` - its name (required);
    * `:reach` - the resources it reaches (default `:all`);
    * `:scale` - time scale: a task of ideal duration `d` ms is given `d * scale * pace`
      ms (default 1.0; 0.01 runs the thesis's 2 s tasks as 20 ms);
    * `:pace` - this robot's slowness factor (default 1.0);
    * `:jitter` - each execution takes a factor in `1 ± jitter` more, drawn from `:seed`,
      the robot, the job and the task (default 0.0: equal durations);
    * `:seed` - seed of the jitter (default 0);
    * `:off` - starts out of service, until `write(:robot, :join)` (default false).

  ## What agents do with it (Algorithm 3)

    * `read(:robot, :state)` - `{:ok, %{state:, busy:, off:, retiring:, running:, job:,
      executions:}}`: `busy` is the agent that claimed it, `running` the names of the
      tasks it runs now (nil when it runs none), `job` the last `{job, seq}` it ran,
      `executions` how many tasks it ran so far;
    * `write(:robot, {:claim, look_for, needs, agent})` - atomically: if the robot is in
      state `look_for`, idle, in service, and (for a free robot) reaches every resource in
      `needs`, it is now busy with `agent`; else `{:error, :no_match}`;
    * `write(:robot, {:unclaim, agent})` - gives a claim back (before any run);
    * `write(:robot, {:run, agent, run})` - runs `run.tasks` one after another (each
      task's program's `run/1`, timed), then goes to state `run.next` and sends the event
      `{:finished, agent, reports}` to its subscribers (the agent that claimed it);
    * `write(:robot, :retire)` - battery low: finish the current job, then leave (state
      `:off` once free; it takes no more work);
    * `write(:robot, :join)` - a robot started with `off: true` joins the floor (robot
      addition while running).

  ## The state-transition database (on-the-fly programming, §4.5.4)

  Sequence agents (`TartarusWarehouse.SequenceAgent`) change it with
  `write(:robot, {:db, changes})`, `changes` every change the distributor made so far,
  numbered (`[{1, change}, ..., {n, change}]`): each change travels in its own agent, so a
  robot may meet the second before the first (an insertion and its deletion issued
  together), or never meet one (lost with the distributor's host); it applies the changes
  after the last one it applied, in their order, and ignores those it already applied:

    * `{:insert, after_task, new_task}` - a robot that finishes a block ending with
      `after_task` goes to `{:inserted, new_task, next}` instead of `next`: it waits for
      the agent of `new_task` (which looks for `{:inserted, new_task}` and leaves the robot
      in `next`, the state it would have had);
    * `{:delete, task}` - `task` is no longer run: an agent that brings it finds the robot
      skipping it (recorded with `skipped: true`, holding nothing), an insertion of it is
      removed, and a robot waiting for it goes on to its next state at once (a robot that
      already passed the modified point continues without redoing anything).

  `read(:robot, :history)` gives every execution, oldest first: maps with `robot, job,
  seq, task, resources, agent, claimed_us, start_us, stop_us, ms, ideal_ms` (times are
  `Tartarus.Clock.system_time(:microsecond)`; `claimed_us`: when the agent claimed the robot for
  the block the task belongs to). It is the event log the checker reads
  (`TartarusWarehouse.Checker`).
  """
  @behaviour Tartarus.Plugin

  alias Tartarus.Clock

  @doc """
  Every execution the robots ran so far (`robot_hosts`: `%{name => host}` or a list of
  `{name, host}`, each with this plugin attached as `:robot`), by start time: the event
  log `TartarusWarehouse.Checker` reads. A robot that cannot be read adds nothing.
  """
  @spec history(Enumerable.t()) :: [map()]
  def history(robot_hosts) do
    robot_hosts
    |> Enum.flat_map(fn {_, host} ->
      case Tartarus.read_plugin(host, :robot, :history) do
        {:ok, list} -> list
        _ -> []
      end
    end)
    |> Enum.sort_by(& &1.start_us)
  end

  @impl true
  def init(opts) do
    case Keyword.fetch(opts, :robot) do
      {:ok, name} ->
        {:ok,
         %{
           robot: name,
           reach: reach(Keyword.get(opts, :reach, :all)),
           scale: Keyword.get(opts, :scale, 1.0),
           pace: Keyword.get(opts, :pace, 1.0),
           jitter: Keyword.get(opts, :jitter, 0.0),
           seed: Keyword.get(opts, :seed, 0),
           state: :free,
           busy: nil,
           claimed_us: nil,
           retiring: false,
           off: Keyword.get(opts, :off, false),
           running: nil,
           last_job: nil,
           inserts: %{},
           deleted: MapSet.new(),
           db_version: 0,
           history: []
         }}

      :error ->
        {:error,
         "invalid options given to TartarusWarehouse.Robot: required option :robot not given"}
    end
  end

  defp reach(:all), do: :all
  defp reach(list), do: MapSet.new(list)

  @impl true
  def describe(s),
    do: %{
      kind: :robot,
      robot: s.robot,
      reads: [:state, :history],
      writes: [:claim, :run, :retire]
    }

  @impl true
  def read(:state, s) do
    running = if s.running, do: Enum.map(s.running.tasks, & &1.name)

    {:ok,
     %{
       state: s.state,
       busy: s.busy,
       off: s.off,
       retiring: s.retiring,
       running: running,
       job: s.last_job,
       executions: length(s.history)
     }, s}
  end

  def read(:db, s),
    do:
      {:ok,
       %{
         inserts: s.inserts,
         deleted: s.deleted,
         version: s.db_version
       }, s}

  def read(:history, s), do: {:ok, Enum.reverse(s.history), s}
  def read(other, s), do: {:error, {:bad_argument, other}, s}

  @impl true
  def write({:claim, look_for, needs, agent}, s) do
    if s.busy == nil and not s.off and matches?(s.state, look_for) and
         (look_for != :free or (not s.retiring and reaches?(s, needs))) do
      {:ok, %{s | busy: agent, claimed_us: Clock.system_time(:microsecond)}}
    else
      {:error, :no_match, s}
    end
  end

  def write({:run, agent, run}, %{busy: agent} = s) do
    robot = self()
    ctx = Map.take(s, [:robot, :scale, :pace, :jitter, :seed, :deleted, :claimed_us])
    {job, seq} = if match?({:inserted, _, _}, s.state), do: job_of(s), else: {run.job, run.seq}

    spawn_link(fn ->
      reports = Enum.map(run.tasks, &execute(&1, %{run | job: job, seq: seq}, agent, ctx))
      send(robot, {:robot_finished, agent, reports})
    end)

    {:ok, %{s | running: run, last_job: {job, seq}}}
  end

  def write({:run, _agent, _run}, s), do: {:error, :not_claimed, s}

  def write(:retire, s) do
    s = %{s | retiring: true}
    {:ok, if(s.state == :free and s.busy == nil, do: %{s | off: true}, else: s)}
  end

  def write({:unclaim, agent}, %{busy: agent, running: nil} = s), do: {:ok, %{s | busy: nil}}
  def write({:unclaim, _agent}, s), do: {:ok, s}

  def write(:join, s), do: {:ok, %{s | off: false, retiring: false}}

  def write({:db, changes}, s) when is_list(changes) do
    {:ok,
     Enum.reduce(changes, s, fn
       {n, change}, s when n == s.db_version + 1 -> db_change(%{s | db_version: n}, change)
       _, s -> s
     end)}
  end

  def write(other, s), do: {:error, {:bad_argument, other}, s}

  @impl true
  def handle_info({:robot_finished, agent, reports}, %{busy: agent} = s) do
    run = s.running
    next = if run.next == :resume, do: resume_of(s.state), else: run.next

    next =
      case Map.get(s.inserts, List.last(run.tasks).name) do
        nil -> next
        task -> {:inserted, task, next}
      end

    off = s.off or (s.retiring and next == :free)

    s = %{
      s
      | state: next,
        busy: nil,
        off: off,
        running: nil,
        history: Enum.reverse(reports) ++ s.history
    }

    {:events, [{:finished, agent, reports}], s}
  end

  def handle_info(_msg, s), do: {:events, [], s}

  defp db_change(s, {:insert, after_task, task}),
    do: %{
      s
      | inserts: Map.put(s.inserts, after_task, task),
        deleted: MapSet.delete(s.deleted, task)
    }

  defp db_change(s, {:delete, task}) do
    inserts = for {a, t} <- s.inserts, t != task, into: %{}, do: {a, t}
    s = %{s | inserts: inserts, deleted: MapSet.put(s.deleted, task)}

    case s.state do
      {:inserted, ^task, next} when s.busy == nil -> %{s | state: next}
      _ -> s
    end
  end

  defp matches?(state, state), do: true
  defp matches?({:inserted, task, _next}, {:inserted, task}), do: true
  defp matches?(_state, _look_for), do: false

  defp resume_of({:inserted, _task, next}), do: next
  defp resume_of(_state), do: :free

  # The job an inserted task runs for: the one the robot resumes, else (inserted after a
  # job's last block) the last one it worked for.
  defp job_of(%{state: {:inserted, _task, {job, seq, _i}}}), do: {job, seq}
  defp job_of(s), do: s.last_job || {nil, nil}

  defp reaches?(%{reach: :all}, _needs), do: true
  defp reaches?(%{reach: reach}, needs), do: Enum.all?(needs, &MapSet.member?(reach, &1))

  defp execute(task, run, agent, ctx) do
    if MapSet.member?(ctx.deleted, task.name),
      do: skip(task, run, agent, ctx),
      else: perform(task, run, agent, ctx)
  end

  defp skip(task, run, agent, ctx) do
    now = Clock.system_time(:microsecond)

    %{
      robot: ctx.robot,
      job: run.job,
      seq: run.seq,
      task: task.name,
      resources: [],
      agent: agent,
      claimed_us: ctx.claimed_us,
      start_us: now,
      stop_us: now,
      ms: 0.0,
      ideal_ms: task.duration_ms,
      skipped: true
    }
  end

  defp perform(task, run, agent, ctx) do
    ms = task.duration_ms * ctx.scale * ctx.pace * factor(ctx, run.job, task.name)
    start = Clock.system_time(:microsecond)
    t0 = Clock.monotonic_time(:microsecond)
    task.program.run(%{job: run.job, task: task.name, robot: ctx.robot, ms: ms})
    took = Clock.monotonic_time(:microsecond) - t0

    %{
      robot: ctx.robot,
      job: run.job,
      seq: run.seq,
      task: task.name,
      resources: task.resources,
      agent: agent,
      claimed_us: ctx.claimed_us,
      start_us: start,
      stop_us: start + took,
      ms: took / 1000,
      ideal_ms: task.duration_ms,
      skipped: false
    }
  end

  defp factor(%{jitter: j}, _job, _task) when j == 0, do: 1.0

  defp factor(ctx, job, task) do
    {u, _} =
      :rand.uniform_s(
        :rand.seed_s(:exsss, {ctx.seed, :erlang.phash2(ctx.robot), :erlang.phash2({job, task})})
      )

    1.0 + ctx.jitter * (2 * u - 1)
  end
end
