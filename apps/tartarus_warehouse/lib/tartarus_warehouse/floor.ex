defmodule TartarusWarehouse.Floor do
  @moduledoc """
  A warehouse floor on the emulator, one process (a GenServer) that owns it: it builds the
  floor (`TartarusWarehouse.Floor.Build`: the network of §4.7.1, a robot plugin on each
  robot host, the distributor or the central server), takes jobs and changes
  (`TartarusWarehouse.Floor.Changes`), counts the jobs done, and takes the floor down
  when stopped. Options are checked before anything starts
  (`TartarusWarehouse.Floor.Options`).

  One driver, two ways to use it:

    * `run/1` runs a batch of jobs and returns what happened: it is `start/1`, the jobs
      submitted (at their arrival times), `await/2` and `stop/1`, with the batch's events
      (`{n, event}` once n jobs completed, `{{:ms, t}, event}` t ms after the submission)
      fired by the floor;
    * `start/1` starts a floor that stays up until `stop/1`: submit jobs when you like
      (`submit/2`), change it while it runs (`change/2`: insert or delete a task, retire a
      robot, let a standby robot join), look at it (`status/1`, or the web dashboard with
      `dashboard: port`), wait for the jobs (`await/2`), and `stop/1` it for what ran:

      iex> {:ok, f} = TartarusWarehouse.Floor.start(robots: 2, resources: [:rack, :bay])
      iex> TartarusWarehouse.Floor.submit(f, %{id: 1, tasks: [%{name: "T1", resources: [:rack]}]})
      :ok
      iex> {:error, _message} = TartarusWarehouse.Floor.submit(f, %{id: 2, tasks: [%{name: "T1", resources: [:dock]}]})
      iex> TartarusWarehouse.Floor.await(f, 10_000)
      :ok
      iex> {:ok, r} = TartarusWarehouse.Floor.stop(f)
      iex> {r.jobs, r.timed_out, r.mutex_violations}
      {[1], [], 0}
  """

  use GenServer

  alias Tartarus.Clock
  alias TartarusDashboard.Panel
  alias TartarusWarehouse.{Checker, Job}
  alias TartarusWarehouse.Floor.{Build, Changes, Options}

  @doc "The options of `run/1` (see `TartarusWarehouse.Floor.Options`)."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: Options.schema()

  @doc """
  The floor's topology for `robots` robots, `secondary` relay nodes and `phi`
  shared-resource nodes (see `TartarusWarehouse.Floor.Build.topology/3`).
  """
  @spec topology(pos_integer(), non_neg_integer(), non_neg_integer()) ::
          TartarusEmu.Topology.t()
  defdelegate topology(robots, secondary, phi \\ 0), to: Build

  @doc """
  Runs jobs on a floor: `start/1`, the jobs submitted, `await/2` (at most `timeout_ms`),
  `stop/1`. Options:

  #{Tartarus.Options.docs(TartarusWarehouse.Floor.Options.schema())}

  Returns `{:ok, result}`: what `stop/1` returns (`history`, every execution: see
  `TartarusWarehouse.Robot`; `jobs`, ids in submission order; `completed`, id =>
  completion time, µs; `t0_us`, the submission of the first job; `makespan_ms`; `robots`;
  `migrations`, `bytes`, `messages` from `TartarusEmu.Log`; `rack_codes`, the code each
  rack received with `phi_agents` (`TartarusWarehouse.Rack`); `timed_out`, the jobs not
  done; `refused_events`, the events that were refused and changed nothing, with the
  reason; `applied_events`, each with the time it took effect, µs; `killed_at_us`;
  `failed`, nil or why the distributor failed: its jobs are then lost and `run/1` stops
  waiting for them; `mutex_violations`; `changes`), `wall_ms` (the machine's time the run
  took, `Tartarus.Clock.machine_time/1`) and `duration_ms` (the run's time on the floor's
  own clock, `Tartarus.Clock.monotonic_time/1`: in virtual time, the emulated time); or
  `{:error, message}` for bad options or a rejected job.
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts) do
    # wall_ms: the machine's time the run took (the apparatus); duration_ms: the floor's
    # own (design) time, which in virtual time is the emulated time.
    t_start = Clock.machine_time(:millisecond)
    d_start = Clock.monotonic_time(:millisecond)

    with {:ok, opts, world, events} <- Options.check_run(opts),
         {:ok, floor} <- launch(world, opts, %{events: events, owner: self()}) do
      # :ok, {:error, :timeout} or the floor's failure: stop/1's result says which.
      _ = await(floor, opts[:timeout_ms])
      {:ok, r} = stop(floor)

      {:ok,
       Map.merge(r, %{
         wall_ms: Clock.machine_time(:millisecond) - t_start,
         duration_ms: Clock.monotonic_time(:millisecond) - d_start
       })}
    end
  end

  @doc """
  Starts a floor that stays up until `stop/1` (not linked to the caller). Options: those of
  `run/1` (the `jobs` given are submitted at their `arrivals_ms`, at once by default;
  `events`, `retire` and `timeout_ms` are for `run/1`: here, call `change/2`), and
  `dashboard`. Give `resources`
  for jobs to come (by default the floor knows the resources its first jobs name).
  Returns `{:ok, floor}` or `{:error, message}`.
  """
  @spec start(keyword()) :: {:ok, pid()} | {:error, String.t()}
  def start(opts \\ []) do
    with {:ok, opts, world} <- Options.check_start(opts) do
      launch(world, opts, %{events: [], owner: nil})
    end
  end

  # `run` is the batch's events and, for run/1, its caller: the floor stops if it goes.
  defp launch(world, opts, run) do
    case GenServer.start(__MODULE__, {world, opts, run}) do
      {:ok, pid} -> {:ok, pid}
      {:error, {:dashboard, message}} -> {:error, message}
      {:error, reason} -> {:error, "the floor did not start: #{inspect(reason)}"}
    end
  end

  @doc """
  Submits a job (a job spec, see `TartarusWarehouse.Job`) to a started floor: `:ok` (the
  job is accepted: it runs, and is not lost), `{:error, :queue_full}` when the distributor
  would hold more than `max_pending_tasks` tasks of jobs accepted and not completed
  (backpressure: submit it again once a job completed), or `{:error, message}` for a
  malformed job (checked by
  `TartarusWarehouse.Job.plan/2`: the message names the field, what was expected and what
  arrived), an id already submitted, a job that needs a resource an inserted task holds,
  or a floor that failed (see `status/1`); nothing changes then.
  """
  @spec submit(pid(), map()) :: :ok | {:error, :queue_full | String.t()}
  def submit(floor, job), do: GenServer.call(floor, {:submit, job}, 60_000)

  @doc """
  Changes a started floor while it runs: `{:insert, after_task, task_spec}`,
  `{:delete, task}`, `{:retire, i}`, `{:join, i}` or `{:kill_distributor, down_ms}` (see
  `run/1`'s `events`; the kill needs a floor started with `failover: true`, and the floor
  answers nothing else until its distributor's host is back). `:ok`, or `{:error, message}`
  when refused, and nothing changes: a malformed change (checked by
  `TartarusWarehouse.Job.change/2` before anything is asked of the distributor or a
  robot), an unknown robot, a robot whose retirement would leave no robot in service (or
  none in service reaching a resource it reaches: the floor would take jobs it cannot
  run), a task already inserted, or a floor that failed.
  """
  @spec change(pid(), term()) :: :ok | {:error, String.t()}
  def change(floor, event) do
    down_ms =
      case event do
        {:kill_distributor, ms} when is_integer(ms) and ms >= 0 -> ms
        _ -> 0
      end

    GenServer.call(floor, {:change, event}, 60_000 + down_ms)
  end

  @doc """
  What a started floor is doing: `jobs` (ids, in submission order), `done` (ids
  completed), `pending`, `robots` (name => the robot's state, see
  `TartarusWarehouse.Robot`), `hosts` (name => host), `elapsed_ms`, `backlog` (jobs of
  `run/1` or `start/1` waiting in the floor for room at the distributor: see the option
  `max_pending_tasks`), `failed` (nil, or why
  the floor failed: its distributor crashed and lost its jobs, or was removed; the floor
  then takes no more jobs or changes, and `stop/1` still reports what ran) and `errors`
  (oldest first: requests the floor or the distributor could not handle, each answered
  `{:error, message}` to its caller, and the failure).
  """
  @spec status(pid()) :: map()
  def status(floor), do: GenServer.call(floor, :status, 30_000)

  @doc """
  Waits until every job submitted so far completed: `:ok`, `{:error, :timeout}`,
  `{:error, :stopped}` when the floor is stopped meanwhile, or `{:error, message}` when
  the floor failed (at once, or as soon as it fails: see `status/1`).
  """
  @spec await(pid(), timeout()) :: :ok | {:error, :timeout | :stopped | String.t()}
  def await(floor, timeout \\ 60_000) do
    GenServer.call(floor, {:await, timeout}, :infinity)
  end

  @doc """
  Stops a started floor and returns `{:ok, result}`: what ran (`history`, `jobs`,
  `completed`, `timed_out`: the jobs not completed when it stopped, `t0_us`,
  `makespan_ms`, `robots`, `migrations`, `bytes`, `messages`: see
  `TartarusWarehouse.Floor.Build.collect/4`), `mutex_violations` (Eq. 4.1, pairs of
  executions: `TartarusWarehouse.Checker.violations/1`), `changes` (every change, from
  `change/2` or `run/1`'s events, with its time and its result, `:ok` or
  `{:error, reason}`), the same split as `applied_events` (`event`, `at_us`) and
  `refused_events` (`event`, `reason`), `killed_at_us` (when the distributor's host was
  killed) and `failed` (see `status/1`).
  """
  @spec stop(pid()) :: {:ok, map()}
  def stop(floor), do: GenServer.call(floor, :stop, 60_000)

  @impl GenServer
  def init({world, opts, run}) do
    Process.flag(:trap_exit, true)
    if run.owner, do: Process.monitor(run.owner)
    table = opts[:status] || TartarusWarehouse.Panel.new()
    ctx = Build.start(world, Keyword.put(opts, :status, table), self())
    t0 = Clock.system_time(:microsecond)
    :ok = Build.publish(ctx, 0, t0)

    case start_dashboard(opts[:dashboard], ctx, table) do
      {:ok, dash} ->
        st = %{
          ctx: ctx,
          t0: t0,
          jobs: [],
          done: %{},
          waiters: [],
          dash: dash,
          changes: [],
          killed: [],
          failed: nil,
          errors: [],
          events: run.events,
          arriving: 0,
          backlog: []
        }

        {:ok, st |> arrive(opts[:jobs], opts[:arrivals_ms]) |> schedule_events()}

      {:error, message} ->
        Build.stop(ctx)
        {:stop, {:dashboard, message}}
    end
  end

  # Jobs due at once are submitted now, the others when they arrive (`{:arrive, job}`);
  # the events due once 0 jobs completed fire when every job has been submitted.
  defp arrive(st, jobs, []), do: st |> submit_all(jobs) |> fire(0)

  defp arrive(st, jobs, arrivals) do
    timed =
      jobs
      |> Enum.zip(
        arrivals ++ List.duplicate(List.last(arrivals), max(length(jobs) - length(arrivals), 0))
      )
      |> Enum.sort_by(&elem(&1, 1))

    {now, later} = Enum.split_with(timed, fn {_job, at} -> at <= 0 end)
    Enum.each(later, fn {job, at} -> Clock.send_after(self(), {:arrive, job}, at) end)
    st = submit_all(st, Enum.map(now, &elem(&1, 0)))
    if later == [], do: fire(st, 0), else: %{st | arriving: length(later)}
  end

  # The jobs of run/1 and start/1 (planned before the floor started) wait in the floor's
  # backlog, in order, while the distributor is full (`max_pending_tasks`), and go on as jobs
  # complete. Any other refusal is the distributor's, and fails the floor.
  defp submit_all(st, jobs), do: feed(%{st | backlog: st.backlog ++ jobs})

  defp feed(%{failed: nil, backlog: [job | rest]} = st) do
    case do_submit(job, %{st | backlog: rest}) do
      {:ok, st} -> feed(st)
      {{:error, :queue_full}, st} -> %{st | backlog: [job | st.backlog]}
      {{:error, message}, st} -> fail(st, message)
    end
  end

  defp feed(st), do: st

  # `{{:ms, t}, event}`: t ms after `t0` (taken before the first job was submitted).
  defp schedule_events(st) do
    elapsed_ms = div(Clock.system_time(:microsecond) - st.t0, 1000)

    Enum.each(st.events, fn
      {{:ms, t}, event} -> Clock.send_after(self(), {:event_due, event}, max(t - elapsed_ms, 0))
      _ -> :ok
    end)

    st
  end

  # The events due once `count` jobs completed, in the order given; none once the floor
  # failed.
  defp fire(%{failed: nil} = st, count) do
    Enum.reduce(st.events, st, fn
      {^count, event}, st -> fire_one(event, st)
      _, st -> st
    end)
  end

  defp fire(st, _count), do: st

  defp fire_one(event, st) do
    at = Clock.system_time(:microsecond)
    {_result, st} = apply_change(event, st)
    if match?({:kill_distributor, _}, event), do: %{st | killed: [at | st.killed]}, else: st
  end

  # A change, from change/2 or the batch's events, applied and kept with its result.
  defp apply_change(event, st) do
    {result, st} =
      guarded(st, {"change", event}, fn st ->
        {Changes.apply_change(event, st.ctx), st}
      end)

    change = %{event: event, at_us: Clock.system_time(:microsecond), result: result}
    {result, %{st | changes: [change | st.changes]}}
  end

  defp start_dashboard(nil, _ctx, _table), do: {:ok, nil}

  # Linked once started: it goes with the floor.
  defp start_dashboard(spec, ctx, table) do
    with {:ok, dash} <-
           TartarusEmu.Dashboard.serve(ctx.net, spec, [{TartarusWarehouse.Panel, table}]) do
      Process.link(dash)
      {:ok, dash}
    end
  end

  @impl GenServer
  def handle_call({what, _}, _from, %{failed: reason} = st)
      when reason != nil and what in [:submit, :change] do
    {:reply, {:error, failed_message(reason)}, st}
  end

  def handle_call({:submit, job}, _from, st) do
    {reply, st} = guarded(st, {"submit", job}, &do_submit(job, &1))
    {:reply, reply, st}
  end

  def handle_call(
        {:change, {:kill_distributor, _} = event},
        _from,
        %{ctx: %{failover: false}} = st
      ) do
    result =
      {:error,
       "the distributor's host can be killed only on a floor started with failover: true (without it every job stops)"}

    change = %{event: event, at_us: Clock.system_time(:microsecond), result: result}
    {:reply, result, %{st | changes: [change | st.changes]}}
  end

  def handle_call({:change, event}, _from, st) do
    at = Clock.system_time(:microsecond)
    {result, st} = apply_change(event, st)

    st =
      if match?({:kill_distributor, _}, event) and result == :ok,
        do: %{st | killed: [at | st.killed]},
        else: st

    {:reply, result, st}
  end

  def handle_call(:status, _from, st) do
    robots =
      Map.new(st.ctx.robot_hosts, fn {name, host} ->
        case Tartarus.read_plugin(host, :robot, :state) do
          {:ok, state} -> {name, state}
          {:error, reason} -> {name, {:unreachable, reason}}
        end
      end)

    {:reply,
     %{
       jobs: st.jobs,
       done: Enum.filter(st.jobs, &Map.has_key?(st.done, &1)),
       pending: Enum.reject(st.jobs, &Map.has_key?(st.done, &1)),
       robots: robots,
       hosts: st.ctx.robot_hosts,
       elapsed_ms: div(Clock.system_time(:microsecond) - st.t0, 1000),
       backlog: length(st.backlog),
       failed: st.failed,
       errors: Enum.reverse(st.errors)
     }, st}
  end

  def handle_call({:await, timeout}, from, st) do
    cond do
      all_done?(st) -> {:reply, :ok, st}
      st.failed -> {:reply, {:error, failed_message(st.failed)}, st}
      true -> wait(timeout, from, st)
    end
  end

  def handle_call(:stop, from, st), do: stop_call(from, st)

  defp wait(timeout, from, st) do
    ref = make_ref()
    if timeout != :infinity, do: Clock.send_after(self(), {:await_timeout, ref}, timeout)
    {:noreply, %{st | waiters: [{ref, from} | st.waiters]}}
  end

  defp stop_call(_from, st) do
    # Jobs still in the backlog never reached the distributor: not completed.
    result = Build.collect(st.ctx, st.jobs ++ Enum.map(st.backlog, & &1.id), st.done, st.t0)
    changes = Enum.reverse(st.changes)

    result =
      Map.merge(result, %{
        mutex_violations: length(Checker.violations(result.history)),
        changes: changes,
        applied_events: for(%{result: :ok} = c <- changes, do: Map.take(c, [:event, :at_us])),
        refused_events:
          for(%{event: e, result: {:error, reason}} <- changes, do: %{event: e, reason: reason}),
        killed_at_us: Enum.reverse(st.killed),
        failed: st.failed
      })

    Enum.each(st.waiters, fn {_, from} -> GenServer.reply(from, {:error, :stopped}) end)
    # Everything is stopped before the caller hears back.
    shut_down(st)
    {:stop, :normal, {:ok, result}, %{st | waiters: [], dash: nil, ctx: nil}}
  end

  @impl GenServer
  def handle_info({:warehouse_job_done, id, at}, st) do
    st = feed(%{st | done: Map.put(st.done, id, at)})
    Panel.publish(st.ctx.status, &:ets.update_element(&1, :jobs, {3, map_size(st.done)}))
    st = fire(st, map_size(st.done))

    if all_done?(st) do
      Enum.each(st.waiters, fn {_, from} -> GenServer.reply(from, :ok) end)
      {:noreply, %{st | waiters: []}}
    else
      {:noreply, st}
    end
  end

  def handle_info({:arrive, job}, st) do
    st = submit_all(%{st | arriving: st.arriving - 1}, [job])
    {:noreply, if(st.arriving == 0, do: fire(st, 0), else: st)}
  end

  # A batch's timed event; dropped once every job is done (the batch is over) or the floor
  # failed.
  def handle_info({:event_due, event}, st) do
    if st.failed == nil and not all_done?(st),
      do: {:noreply, fire_one(event, st)},
      else: {:noreply, st}
  end

  # run/1's caller is gone: so is its floor.
  def handle_info({:DOWN, _ref, :process, _pid, _reason}, st), do: {:stop, :normal, st}

  def handle_info({:await_timeout, ref}, st) do
    case List.keytake(st.waiters, ref, 0) do
      {{^ref, from}, rest} ->
        GenServer.reply(from, {:error, :timeout})
        {:noreply, %{st | waiters: rest}}

      nil ->
        {:noreply, st}
    end
  end

  # The distributor (or the central server) failed: every job it held is lost. The floor
  # says so (status/1's `failed`), answers its waiters, and takes no more jobs or changes.
  def handle_info({:warehouse_distributor_failed, reason}, st), do: {:noreply, fail(st, reason)}

  def handle_info({:tartarus_removed, id, reason}, %{ctx: %{dref: {id, _}}} = st),
    do: {:noreply, fail(st, "the distributor was removed: #{inspect(reason, limit: 5)}")}

  # A request the distributor could not handle (answered with an error, nothing changed).
  def handle_info({:warehouse_distributor_error, message}, st),
    do: {:noreply, %{st | errors: [message | st.errors]}}

  def handle_info({:EXIT, dash, _reason}, %{dash: dash} = st), do: {:noreply, %{st | dash: nil}}
  def handle_info(_other, st), do: {:noreply, st}

  @impl GenServer
  def terminate(_reason, st), do: shut_down(st)

  defp shut_down(st) do
    if st.dash do
      try do
        TartarusDashboard.stop(st.dash)
      catch
        :exit, _ -> :ok
      end
    end

    if st.ctx, do: Build.stop(st.ctx)
  end

  defp do_submit(job, st) do
    with {:ok, _} <- Job.plan(job, st.ctx.world),
         false <- job.id in st.jobs,
         :ok <- Changes.submit(st.ctx.dref, job) do
      st = %{st | jobs: st.jobs ++ [job.id]}
      Panel.publish(st.ctx.status, &:ets.update_element(&1, :jobs, {2, length(st.jobs)}))
      {:ok, st}
    else
      {:error, message} -> {{:error, message}, st}
      true -> {{:error, "job #{inspect(job.id)} was already submitted"}, st}
    end
  end

  # Every job submitted so far completed, and none still to arrive.
  defp all_done?(st),
    do:
      st.arriving == 0 and st.backlog == [] and map_size(st.done) >= length(st.jobs) and
        Enum.all?(st.jobs, &Map.has_key?(st.done, &1))

  defp fail(%{failed: nil} = st, reason) do
    Enum.each(st.waiters, fn {_, from} ->
      GenServer.reply(from, {:error, failed_message(reason)})
    end)

    %{st | failed: reason, waiters: [], errors: [reason | st.errors]}
  end

  defp fail(st, _reason), do: st

  defp failed_message(reason),
    do: "the floor failed (#{reason}): it takes no more jobs or changes; stop/1 it for what ran"

  # An exception while the floor handles a request is the caller's answer, `{:error,
  # message}`, and is kept in status/1's `errors`; the floor goes on, unchanged.
  # `what` is `{verb, term}`, inspected only for the message: a change fired at its time
  # pays nothing for it.
  defp guarded(st, {verb, term}, fun) do
    fun.(st)
  catch
    kind, reason ->
      message =
        "the floor could not #{verb} #{inspect(term, limit: 5)}: " <>
          Exception.format_banner(kind, reason, __STACKTRACE__)

      {{:error, message}, %{st | errors: [message | st.errors]}}
  end
end
