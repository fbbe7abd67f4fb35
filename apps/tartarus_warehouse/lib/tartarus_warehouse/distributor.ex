defmodule TartarusWarehouse.Distributor do
  @moduledoc """
  The Job Distributor of Algorithm 2 (thesis §4.5.1) as a pure state machine:
  `(distributor, event) -> {distributor, actions}`. `TartarusWarehouse.DistributorAgent`
  runs it on the distributor's host and carries the actions out.

  ## What it decides

  A job is planned (`TartarusWarehouse.Job.plan/2`: sequences of blocks, case A, B or C)
  and each block becomes an **assignment**: the tasks an agent carries, their resources,
  and the state information (SI): the robot state to look for and the state to leave the
  robot in. Robot states are `:free` (the thesis's S1*) and `{job, sequence, index}`
  ("booked for this job's sequence, next block `index`"): the first block of a sequence
  looks for a free robot, the last one leaves it free.

  Assignments wait in one queue, in the order jobs arrived. One pass over the queue
  releases each assignment whose resources no released agent holds and no assignment
  before it is waiting for (first come, first served per resource: a later job never
  overtakes an earlier one on a resource, so none starves), with one more rule for first
  blocks: a sequence's first block is released only once the previous first block has
  booked a robot (`started/2`). Robots are thus booked in job order, and the oldest
  unfinished sequence can always go on: its next block's resources are held by nobody
  older and wanted by nobody younger, and its robot (or, for a first block, every robot,
  all being free or booked by older sequences that finish) is there to be found. That
  removes the hold-and-wait the thesis leaves open (§4.5.6).

  The distributor keeps the list of resources held (§4.5.1: "the same resource is not
  assigned to other agents"): an agent is the one token of its resources from its release
  until it reports `done/2`. The agent that reports is re-issued for the next job when
  an assignment now released needs no resource beyond the ones it held (§4.5.2: "this
  task and resource is then assigned ... for the next job"); otherwise it retires.

  ## Actions

    * `{:release, ref, assignment}` - start a new task agent `ref` carrying `assignment`;
    * `{:reissue, ref, assignment}` - the agent `ref` that just reported carries
      `assignment` next;
    * `{:retire, ref}` - the agent `ref` that just reported stops;
    * `{:job_done, job_id}` - every task of the job ran;
    * `{:sequence, changes}` - release a sequence agent that writes the newest change into
      every robot's state-transition database (on-the-fly programming, below). `changes`
      is every change so far, numbered (`[{1, change}, ..., {n, change}]`): changes travel
      concurrently, each in its own agent, so a robot may meet them out of order, and an
      agent lost with the distributor's host (an effect that never ran) leaves a gap; a
      robot applies the changes it has not applied yet, in order, from whichever agent
      comes first.

  ## On-the-fly programming (§4.5.4)

  `insert/3` adds a task after another one: a sequence agent tells every robot to wait,
  after that task, for the new task's agent, which is released like any other (first come,
  first served on its resources) and keeps serving robots (and holding its resources)
  until `delete/2` removes the task; it then retires as soon as it reports, or when it asks
  `still/2` after a round without work. `delete/2` of a job's own task only tells the
  robots (they skip it).

  ## Agents that continue (the other reading of §4.5.2)

  With `continue: true` an agent released (or re-issued) for a block also gets the
  **run** of the blocks of the jobs queued after it that are the same block (the same
  sequence and place in it, tasks, resources): `follow` in its assignment, in job order
  (the run stops at the first queued block that wants its resources and is not the same
  block, and a first block's run at any other first block). It serves them one after the
  other without returning ("μ1 continues to make all robots in state S1* to perform task
  T1 sequentially"), holding its resources throughout, and reports `done/2` at the end of
  its run only; a sequence's last block within the run is reported one way with
  `progress/3` (so the distributor knows when a job is done). A job is then done when
  each of its sequences' last block is reported. A first block's run keeps the next first
  blocks waiting until it ends, so robots are still booked in job order.

      iex> alias TartarusWarehouse.Distributor, as: D
      iex> d = D.new(TartarusWarehouse.Job.world([:a, :b], 2), continue: true)
      iex> job = %{id: 1, tasks: [%{name: "T1", resources: [:a]}, %{name: "T2", resources: [:b], after: ["T1"]}]}
      iex> {:ok, d, _} = D.submit(d, job)
      iex> {:ok, d, []} = D.submit(d, %{job | id: 2})
      iex> {:ok, d, []} = D.submit(d, %{job | id: 3})
      iex> {d, [{:reissue, 1, a}]} = D.done(d, 1)
      iex> {a.job, Enum.map(a.follow, & &1.job)}
      {2, [3]}
      iex> {d, [{:job_done, 1}, {:reissue, 2, b}]} = D.done(d, 2)
      iex> {b.job, Enum.map(b.follow, & &1.job)}
      {2, [3]}
      iex> {d, [{:job_done, 2}]} = D.progress(d, 2, {2, 0, 1})
      iex> {_d, [{:job_done, 3}, {:retire, 2}]} = D.done(d, 2)

  ## Example

      iex> alias TartarusWarehouse.Distributor, as: D
      iex> d = D.new(TartarusWarehouse.Job.world([:a, :b], 2))
      iex> job = %{id: 1, tasks: [%{name: "T1", resources: [:a]}, %{name: "T2", resources: [:b], after: ["T1"]}]}
      iex> {:ok, d, actions} = D.submit(d, job)
      iex> for {:release, ref, a} <- actions, do: {ref, a.look_for, a.next}
      [{1, :free, {1, 0, 1}}, {2, {1, 0, 1}, :free}]
      iex> {:ok, d, []} = D.submit(d, %{job | id: 2})
      iex> {d, []} = D.started(d, 1)
      iex> {d, [{:reissue, 1, next}]} = D.done(d, 1)
      iex> {next.job, next.look_for}
      {2, :free}
      iex> D.waiting(d)
      1
  """

  alias TartarusWarehouse.Job

  @typedoc "A robot's state: free (S1*), or booked for a job's sequence, waiting for a block."
  @type robot_state ::
          :free | {job :: term(), sequence :: non_neg_integer(), index :: pos_integer()}

  @typedoc "What one task agent carries."
  @type assignment :: %{
          job: term(),
          seq: non_neg_integer(),
          index: non_neg_integer(),
          tasks: [Job.task()],
          resources: [Job.resource()],
          needs: [Job.resource()],
          look_for: robot_state(),
          next: robot_state()
        }

  @typedoc "An agent's reference (the distributor's own numbering)."
  @type ref :: pos_integer()

  @typedoc "An action for the process that runs the distributor."
  @type action ::
          {:release, ref(), assignment()}
          | {:reissue, ref(), assignment()}
          | {:retire, ref()}
          | {:job_done, term()}
          | {:sequence,
             [{pos_integer(), {:insert, String.t(), String.t()} | {:delete, String.t()}}]}

  @typedoc "The distributor."
  @type t :: %__MODULE__{
          world: Job.world(),
          queue: [assignment()],
          held: %{Job.resource() => ref()},
          out: %{ref() => assignment()},
          jobs: %{term() => non_neg_integer()},
          starting: ref() | nil,
          next_ref: pos_integer(),
          completed: MapSet.t(term()),
          inserted: %{String.t() => boolean()},
          inserts: %{String.t() => %{after: String.t(), resources: [Job.resource()]}},
          names: MapSet.t(String.t()),
          deleted: MapSet.t(String.t()),
          max_pending_tasks: pos_integer() | :infinity,
          pending_tasks: non_neg_integer(),
          sizes: %{term() => pos_integer()}
        }

  defstruct world: nil,
            queue: [],
            held: %{},
            out: %{},
            jobs: %{},
            starting: nil,
            next_ref: 1,
            completed: MapSet.new(),
            inserted: %{},
            # the insertions in effect (not deleted): name => what it follows, its resources
            inserts: %{},
            # every task name of the jobs submitted so far, and those deleted
            names: MapSet.new(),
            deleted: MapSet.new(),
            changes: [],
            continue: false,
            runs: MapSet.new(),
            max_pending_tasks: :infinity,
            # the tasks of the jobs accepted and not completed, and each such job's tasks
            pending_tasks: 0,
            sizes: %{}

  @doc """
  A distributor for `world` (see `TartarusWarehouse.Job.world/2`). With `continue: true`
  an agent is given runs of blocks (see "Agents that continue" above); `max_pending_tasks` (a
  positive integer, default `:infinity`) bounds the tasks of the jobs accepted and not yet
  completed (see `submit/2`).
  """
  @spec new(Job.world(), keyword()) :: t()
  def new(world, opts \\ []),
    do: %__MODULE__{
      world: world,
      continue: Keyword.get(opts, :continue, false),
      max_pending_tasks: Keyword.get(opts, :max_pending_tasks, :infinity)
    }

  @doc """
  A job arrives (asynchronously, at any time). Returns `{:ok, distributor, actions}`, or
  `{:error, :queue_full}` when its tasks would take those of the jobs accepted and not yet
  completed beyond `max_pending_tasks` (the submitter may try again once one completes), or
  `{:error, message}` for a malformed spec (see `TartarusWarehouse.Job.plan/2`), a job id
  already in use, a job of more tasks than `max_pending_tasks`, or a job that needs a
  resource an inserted task holds (an inserted task's agent holds its resources until the
  task is deleted: see `insert/3`); the distributor is then unchanged.

      iex> alias TartarusWarehouse.Distributor, as: D
      iex> d = D.new(TartarusWarehouse.Job.world([:a], 1), max_pending_tasks: 1)
      iex> {:ok, d, _} = D.submit(d, %{id: 1, tasks: [%{name: "T1", resources: [:a]}]})
      iex> D.submit(d, %{id: 2, tasks: [%{name: "T1", resources: [:a]}]})
      {:error, :queue_full}
  """
  @spec submit(t(), map()) :: {:ok, t(), [action()]} | {:error, :queue_full | String.t()}
  def submit(%__MODULE__{} = d, spec) do
    with :ok <- room(d, 1),
         {:ok, plan} <- Job.plan(spec, d.world),
         :ok <- new_id(d, plan.id),
         tasks = for(seq <- plan.sequences, b <- seq, t <- b.tasks, do: t),
         :ok <- room(d, length(tasks), plan.id),
         :ok <- clear_of_inserts(d, plan.id, tasks) do
      assignments = assignments(plan)

      d = %{
        d
        | queue: d.queue ++ assignments,
          pending_tasks: d.pending_tasks + length(tasks),
          sizes: Map.put(d.sizes, plan.id, length(tasks)),
          names: Enum.reduce(tasks, d.names, &MapSet.put(&2, &1.name)),
          jobs:
            Map.put(
              d.jobs,
              plan.id,
              if(d.continue, do: length(plan.sequences), else: length(assignments))
            )
      }

      {d, actions} = issue(d, nil)
      {:ok, d, actions}
    end
  end

  # Room for `n` more tasks; a job larger than the bound itself never fits.
  defp room(d, n, id \\ nil) do
    cond do
      d.max_pending_tasks == :infinity ->
        :ok

      n > d.max_pending_tasks ->
        {:error,
         "job #{inspect(id)} has #{n} tasks, more than the distributor holds at once (max_pending_tasks: #{d.max_pending_tasks})"}

      d.pending_tasks + n > d.max_pending_tasks ->
        {:error, :queue_full}

      true ->
        :ok
    end
  end

  defp new_id(d, id) do
    if Map.has_key?(d.jobs, id) or MapSet.member?(d.completed, id),
      do: {:error, "job id #{inspect(id)} is already in use"},
      else: :ok
  end

  # A job's task that needs a resource an insertion in effect holds would wait until the
  # insertion is deleted; one named like an inserted task would be deleted with it.
  defp clear_of_inserts(d, id, tasks) do
    Enum.find_value(tasks, :ok, fn t ->
      cond do
        Map.has_key?(d.inserts, t.name) ->
          {:error,
           "job #{inspect(id)}: task #{inspect(t.name)} has the name of an inserted task (delete it first)"}

        holder = inserted_holder(d, t.resources) ->
          {name, r} = holder

          {:error,
           "job #{inspect(id)}: task #{inspect(t.name)} needs #{inspect(r)}, which inserted task #{inspect(name)} holds until it is deleted"}

        true ->
          nil
      end
    end)
  end

  # The insertion in effect (other than `except`) that holds one of `resources`, and that
  # resource, or nil.
  defp inserted_holder(d, resources, except \\ nil) do
    Enum.find_value(d.inserts, fn {name, i} ->
      case if(name != except, do: Enum.filter(resources, &(&1 in i.resources)), else: []) do
        [r | _] -> {name, r}
        [] -> nil
      end
    end)
  end

  @doc """
  The plan's blocks as assignments, in order (sequence by sequence). A sequence's first
  block `needs` every resource of the sequence (the free robot it books must reach them
  all); the later blocks need nothing more than the robot already booked.
  """
  @spec assignments(Job.plan()) :: [assignment()]
  def assignments(plan) do
    for {blocks, s} <- Enum.with_index(plan.sequences),
        needs = blocks |> Enum.flat_map(& &1.resources) |> Enum.uniq() |> Enum.sort(),
        last = length(blocks) - 1,
        {b, i} <- Enum.with_index(blocks) do
      %{
        job: plan.id,
        seq: s,
        index: i,
        tasks: b.tasks,
        resources: b.resources,
        # what a free robot must reach: only a first block looks for one (the later ones
        # go to the robot it booked), so only it carries them (a list a block would make a
        # job's memory grow with the square of its blocks)
        needs: if(i == 0, do: needs, else: []),
        look_for: if(i == 0, do: :free, else: {plan.id, s, i}),
        next: if(i == last, do: :free, else: {plan.id, s, i + 1})
      }
    end
  end

  @doc """
  Agent `ref`, carrying a first block, has booked a robot: the next first block may go.
  Unknown refs are ignored.
  """
  @spec started(t(), ref()) :: {t(), [action()]}
  def started(%__MODULE__{starting: ref} = d, ref) when ref != nil do
    # A first block's run books its robots in job order itself: the next first block
    # waits until the run ends.
    if MapSet.member?(d.runs, ref), do: {d, []}, else: issue(%{d | starting: nil}, nil)
  end

  def started(%__MODULE__{} = d, _ref), do: {d, []}

  @doc """
  Agent `ref` has run its tasks: its resources are free again. The agent is re-issued or
  retired (exactly one of `{:reissue, ref, _}`, `{:retire, ref}` is among the actions).
  Unknown refs get `{:retire, ref}` and change nothing else.
  """
  @spec done(t(), ref()) :: {t(), [action()]}
  def done(%__MODULE__{} = d, ref) do
    case Map.pop(d.out, ref) do
      {nil, _} ->
        {d, [{:retire, ref}]}

      {%{persistent: true} = a, _out} ->
        if Map.get(d.inserted, inserted_name(a), false),
          do: {d, [{:reissue, ref, a}]},
          else: free_persistent(d, ref, a)

      {a, out} ->
        held = Map.drop(d.held, a.resources)
        {d, finished} = count_done(d, a)

        # A first block that ends before it reported started (it cannot, but be safe), or
        # a first block's run that ends.
        d = if d.starting == ref, do: %{d | starting: nil}, else: d
        d = %{d | runs: MapSet.delete(d.runs, ref)}
        {d, actions} = issue(%{d | out: out, held: held}, {ref, MapSet.new(a.resources)})

        actions =
          if Enum.any?(actions, &match?({:reissue, ^ref, _}, &1)),
            do: actions,
            else: actions ++ [{:retire, ref}]

        {d, finished ++ actions}
    end
  end

  @doc """
  `continue: true`: agent `ref` finished block `key` (`{job, seq, index}`), a sequence's
  last block within its run, and goes on (a one-way note). Returns `{:job_done, job}`
  when that was the job's last sequence; anything else changes nothing.
  """
  @spec progress(t(), ref(), {term(), non_neg_integer(), non_neg_integer()}) ::
          {t(), [action()]}
  def progress(%__MODULE__{continue: true} = d, ref, {job, _seq, _index})
      when is_map_key(d.out, ref) and is_map_key(d.jobs, job),
      do: count_done(d, %{job: job, next: :free})

  def progress(%__MODULE__{} = d, _ref, _key), do: {d, []}

  # A block reported done: one block less of its job (continue: one sequence less, when
  # it was the sequence's last block).
  defp count_done(d, a) do
    left =
      cond do
        not d.continue -> d.jobs[a.job] - 1
        a.next == :free -> d.jobs[a.job] - 1
        true -> d.jobs[a.job]
      end

    if left == 0,
      do:
        {%{
           d
           | jobs: Map.delete(d.jobs, a.job),
             completed: MapSet.put(d.completed, a.job),
             pending_tasks: d.pending_tasks - Map.get(d.sizes, a.job, 0),
             sizes: Map.delete(d.sizes, a.job)
         }, [{:job_done, a.job}]},
      else: {%{d | jobs: Map.put(d.jobs, a.job, left)}, []}
  end

  @doc """
  Inserts task `spec` (a task spec, see `TartarusWarehouse.Job`) after the task named
  `after_task` in every robot's sequence from now on. Returns `{:ok, distributor,
  actions}` (a `{:sequence, [..., {n, {:insert, after_task, name}}]}` and, once its resources are
  free, the `{:release, ref, assignment}` of its agent) or `{:error, message}`, the
  distributor unchanged, for a change that is malformed (`TartarusWarehouse.Job.change/2`)
  or cannot apply:

    * `after_task` is no task of a job submitted so far and no inserted task (robots would
      never meet it, and the new task's agent would hold its resources for nothing);
    * an inserted task already follows `after_task` (a robot waits for one task there:
      delete it first);
    * the task's name is already inserted, or is a job's task;
    * it needs a resource another inserted task holds, or one a job not yet completed
      needs: an inserted task's agent holds its resources until the task is deleted, so
      the robots that reach `after_task` would wait for an agent that never comes, or the
      job for a resource that is never free (jobs submitted later that need it are
      refused, see `submit/2`).

      iex> alias TartarusWarehouse.Distributor, as: D
      iex> d = D.new(TartarusWarehouse.Job.world([:a, :detour], 1))
      iex> {:ok, d, _} = D.submit(d, %{id: 1, tasks: [%{name: "T2", resources: [:a]}]})
      iex> {:ok, d, [{:release, 2, a}, {:sequence, [{1, change}]}]} = D.insert(d, "T2", %{name: "T2A", resources: [:detour]})
      iex> {a.look_for, a.next, change}
      {{:inserted, "T2A"}, :resume, {:insert, "T2", "T2A"}}
      iex> D.insert(d, "T9", %{name: "T9A", resources: [:detour]})
      {:error, ~s(change {:insert, "T9", _}: no job submitted so far has a task "T9", and no inserted task is named so: there is nothing to insert after)}
      iex> {d, [{:reissue, 2, _}]} = D.done(d, 2)
      iex> {:ok, d, [{:sequence, [{1, _}, {2, {:delete, "T2A"}}]}]} = D.delete(d, "T2A")
      iex> D.done(d, 2)
      ...> |> elem(1)
      [{:retire, 2}]
  """
  @spec insert(t(), String.t(), map()) :: {:ok, t(), [action()]} | {:error, String.t()}
  def insert(%__MODULE__{} = d, after_task, spec) do
    with {:ok, {:insert, after_task, task}} <-
           Job.change({:insert, after_task, spec}, d.world),
         :ok <- insertable(d, after_task, task) do
      name = task.name
      resources = task.resources |> Enum.uniq() |> Enum.sort()

      a = %{
        job: {:otfp, name},
        seq: 0,
        index: 1,
        tasks: [task],
        resources: resources,
        needs: [],
        look_for: {:inserted, name},
        next: :resume,
        persistent: true
      }

      d = %{
        d
        | queue: d.queue ++ [a],
          inserted: Map.put(d.inserted, name, true),
          inserts: Map.put(d.inserts, name, %{after: after_task, resources: resources})
      }

      {d, actions} = issue(d, nil)
      {d, change} = change(d, {:insert, after_task, name})
      {:ok, d, actions ++ [change]}
    end
  end

  # Whether an insertion can apply (see insert/3); its message else.
  defp insertable(d, after_task, task) do
    name = task.name
    follower = Enum.find_value(d.inserts, fn {n, i} -> if i.after == after_task, do: n end)

    refusal =
      cond do
        not MapSet.member?(d.names, after_task) and not Map.has_key?(d.inserts, after_task) ->
          "no job submitted so far has a task #{inspect(after_task)}, and no inserted task is named so: there is nothing to insert after"

        Map.get(d.inserted, name) ->
          "task #{inspect(name)} is already inserted"

        MapSet.member?(d.names, name) ->
          "a job already has a task named #{inspect(name)}: an inserted task needs a name of its own"

        follower != nil ->
          "inserted task #{inspect(follower)} already follows #{inspect(after_task)} (delete it first)"

        holder = inserted_holder(d, task.resources, name) ->
          {other, r} = holder

          "task #{inspect(name)} needs #{inspect(r)}, which inserted task #{inspect(other)} holds until it is deleted"

        user = job_using(d, task.resources) ->
          {job, r} = user

          "task #{inspect(name)} needs #{inspect(r)}, which job #{inspect(job)} (not completed) needs: an inserted task holds its resources until it is deleted, and the job would wait for them"

        true ->
          nil
      end

    if refusal,
      do: {:error, "change {:insert, #{inspect(after_task)}, _}: " <> refusal},
      else: :ok
  end

  # A job not yet completed (its blocks waiting or out) that needs one of `resources`, and
  # that resource, or nil.
  defp job_using(d, resources) do
    Enum.find_value(d.queue ++ Map.values(d.out), fn a ->
      case if(Map.has_key?(a, :persistent),
             do: [],
             else: Enum.filter(a.resources, &(&1 in resources))
           ) do
        [r | _] -> {a.job, r}
        [] -> nil
      end
    end)
  end

  @doc """
  Deletes task `name`: an inserted task's agent retires (at once if it was not yet
  released), and robots skip the task from now on. Returns `{:ok, distributor, actions}`,
  or `{:error, message}` when `name` is not a task's name (see
  `TartarusWarehouse.Job.change/2`), names no task of a job submitted so far and no
  inserted task, or names a task already deleted; the distributor is then unchanged.
  """
  @spec delete(t(), String.t()) :: {:ok, t(), [action()]} | {:error, String.t()}
  def delete(%__MODULE__{} = d, name) do
    with {:ok, {:delete, name}} <- Job.change({:delete, name}, d.world),
         :ok <- deletable(d, name),
         do: do_delete(d, name)
  end

  defp deletable(d, name) do
    refusal =
      cond do
        Map.has_key?(d.inserts, name) ->
          nil

        MapSet.member?(d.deleted, name) or Map.has_key?(d.inserted, name) ->
          "task #{inspect(name)} is already deleted"

        not MapSet.member?(d.names, name) ->
          "no job submitted so far has a task #{inspect(name)}, and no inserted task is named so: there is nothing to delete"

        true ->
          nil
      end

    if refusal, do: {:error, "change {:delete, #{inspect(name)}}: " <> refusal}, else: :ok
  end

  defp do_delete(d, name) do
    queue = Enum.reject(d.queue, &(Map.get(&1, :persistent) && inserted_name(&1) == name))

    {inserted, deleted} =
      if Map.has_key?(d.inserts, name),
        do: {Map.put(d.inserted, name, false), d.deleted},
        else: {d.inserted, MapSet.put(d.deleted, name)}

    d = %{
      d
      | queue: queue,
        inserted: inserted,
        inserts: Map.delete(d.inserts, name),
        deleted: deleted
    }

    {d, change} = change(d, {:delete, name})
    {:ok, d, [change]}
  end

  # The distributor's next change to the robots' databases, numbered; the action carries
  # every change so far.
  defp change(d, change) do
    changes = d.changes ++ [{length(d.changes) + 1, change}]
    {%{d | changes: changes}, {:sequence, changes}}
  end

  @doc """
  An inserted task's agent `ref` found no work for a while: if its task was deleted it
  retires now (`{:retire, ref}` among the actions, its resources free); else nothing.
  """
  @spec still(t(), ref()) :: {t(), [action()]}
  def still(%__MODULE__{} = d, ref) do
    case Map.get(d.out, ref) do
      %{persistent: true} = a ->
        if Map.get(d.inserted, inserted_name(a), false),
          do: {d, []},
          else: free_persistent(d, ref, a)

      _ ->
        {d, []}
    end
  end

  defp inserted_name(%{job: {:otfp, name}}), do: name

  defp free_persistent(d, ref, a) do
    d = %{
      d
      | out: Map.delete(d.out, ref),
        held: Map.drop(d.held, a.resources),
        inserted: Map.delete(d.inserted, inserted_name(a))
    }

    {d, actions} = issue(d, nil)
    {d, actions ++ [{:retire, ref}]}
  end

  @doc "Assignments waiting to be released."
  @spec waiting(t()) :: non_neg_integer()
  def waiting(%__MODULE__{queue: q}), do: length(q)

  @doc "Resources held now, each with the agent holding it."
  @spec held(t()) :: %{Job.resource() => ref()}
  def held(%__MODULE__{held: held}), do: held

  @doc "Jobs not yet completed."
  @spec pending_jobs(t()) :: [term()]
  def pending_jobs(%__MODULE__{jobs: jobs}), do: Map.keys(jobs)

  # One pass over the queue (see the moduledoc). `returning` is the agent that just
  # reported, with the resources it held: it takes the first released assignment it covers.
  defp issue(d, returning) do
    {queue, d, actions} =
      pass(d.queue, [], d, [], MapSet.new(), returning, MapSet.size(d.world.resources))

    take_runs(%{d | queue: queue}, Enum.reverse(actions))
  end

  # Once every resource of the world is wanted by a block left waiting, no later block can
  # go: the rest of the queue stays as it is (a pass costs the blocks before that point,
  # not the whole queue).
  defp pass([], kept, d, actions, _blocked, _ret, _all), do: {Enum.reverse(kept), d, actions}

  defp pass(rest, kept, d, actions, blocked, ret, all) do
    if MapSet.size(blocked) >= all,
      do: {Enum.reverse(kept, rest), d, actions},
      else: step(rest, kept, d, actions, blocked, ret, all)
  end

  defp step([a | rest], kept, d, actions, blocked, ret, all) do
    rs = MapSet.new(a.resources)

    free? =
      Enum.all?(a.resources, &(not Map.has_key?(d.held, &1))) and
        MapSet.disjoint?(rs, blocked) and
        (a.index > 0 or d.starting == nil)

    if free? do
      {ref, d, action, ret} =
        case ret do
          {r, covers} ->
            if MapSet.subset?(rs, covers),
              do: {r, d, :reissue, nil},
              else: {d.next_ref, %{d | next_ref: d.next_ref + 1}, :release, ret}

          nil ->
            {d.next_ref, %{d | next_ref: d.next_ref + 1}, :release, nil}
        end

      d = %{
        d
        | out: Map.put(d.out, ref, a),
          held: Enum.reduce(a.resources, d.held, &Map.put(&2, &1, ref)),
          starting: if(a.index == 0, do: ref, else: d.starting)
      }

      pass(rest, kept, d, [{action, ref, a} | actions], blocked, ret, all)
    else
      pass(rest, [a | kept], d, actions, MapSet.union(blocked, rs), ret, all)
    end
  end

  # continue: each agent released or re-issued takes the run of the same block of the
  # jobs queued after it (see "Agents that continue").
  defp take_runs(%__MODULE__{continue: false} = d, actions), do: {d, actions}

  defp take_runs(d, actions) do
    {actions, d} =
      Enum.map_reduce(actions, d, fn
        {kind, ref, a}, d when kind in [:release, :reissue] and not is_map_key(a, :persistent) ->
          case run_of(a, d.queue) do
            {[], _} ->
              {{kind, ref, a}, d}

            {run, queue} ->
              runs = if a.index == 0, do: MapSet.put(d.runs, ref), else: d.runs
              d = %{d | queue: queue, out: Map.put(d.out, ref, List.last(run)), runs: runs}
              {{kind, ref, Map.put(a, :follow, run)}, d}
          end

        other, d ->
          {other, d}
      end)

    {d, actions}
  end

  defp run_of(a, queue) do
    same = shape(a)
    rs = MapSet.new(a.resources)

    {run, rest, _stopped} =
      Enum.reduce(queue, {[], [], false}, fn b, {run, rest, stopped} ->
        cond do
          stopped ->
            {run, [b | rest], true}

          shape(b) == same and not Map.has_key?(b, :persistent) ->
            {[b | run], rest, false}

          not MapSet.disjoint?(MapSet.new(b.resources), rs) or (a.index == 0 and b.index == 0) ->
            {run, [b | rest], true}

          true ->
            {run, [b | rest], false}
        end
      end)

    {Enum.reverse(run), Enum.reverse(rest)}
  end

  defp shape(a), do: {a.seq, a.index, Enum.map(a.tasks, & &1.name), a.resources, a.needs}
end
