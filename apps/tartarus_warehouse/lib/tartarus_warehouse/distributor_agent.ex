defmodule TartarusWarehouse.DistributorAgent do
  @moduledoc """
  The Job Distributor's process: a static agent on the distributor's host that runs the
  pure `TartarusWarehouse.Distributor` and carries out its actions: it creates task agents
  (`TartarusWarehouse.TaskAgent`) on its host, hands a returning agent its next
  assignment, and tells its owner `{:warehouse_job_done, job_id, time_us}` when a job
  completes.

  Requests it answers: `{:submit, job_spec}` (`:ok`, `{:error, :queue_full}` when the job
  would take the tasks of the jobs accepted and not yet completed beyond
  `max_pending_tasks`, or `{:error, message}`; jobs
  arrive at any time; the same job submitted again is `:ok` and changes nothing),
  `{:insert, after_task, task_spec}` and `{:delete, task}` (on-the-fly programming: it
  releases a `TartarusWarehouse.SequenceAgent`), `{:started, ref}`, `{:done, ref, key}`,
  `{:still, ref}` and `{:valid, ref, nonce}` from task agents, `{:progress, ref, key}`
  (one way, from an agent that continues to the next job: see
  `TartarusWarehouse.Distributor`, "Agents that continue"), `:status`.

  ## Service time

  `service_ms` (a number, default 0) is the distributor's time for each message it
  handles (every request and note above but `:status`), charged as the central
  server's (`TartarusWarehouse.Central`): one FIFO server (`TartarusWarehouse.Service`)
  that handles a message only once its service is done. Agents it creates or re-issues in
  an answer are not charged again.

  ## Surviving the loss of its host

  The distributor is the design's one central point. With `validate: true` its state is
  checkpointed (`Tartarus.Agent.checkpoint/0`) after every change, and on a host started with
  `:data_dir` that checkpoint is journaled: a host killed and started again restores the
  distributor where its last checkpoint left it. What it does to the world (creating
  agents, answering, telling the owner) happens only **after** the change that decided
  it is checkpointed, from a list of pending effects kept in the state, so a restart
  redoes what it may not have done, never forgets it:

    * an answer lost with the host is asked again (task agents retry while the
      distributor is unreachable) and answered again from the last answer kept per agent
      (`{:done, ref, key}` carries which assignment is done, so a repeated report is
      recognized);
    * an agent created just before the host died may be created again after the restart
      with a new nonce; with `validate: true` every task agent asks `{:valid, ref, nonce}`
      after claiming a robot and before running anything, so the stale copy retires
      without running its tasks: no task runs twice and no resource has two tokens;
    * a job completion may be told twice (the owner counts job ids).
  """
  use Tartarus.Agent

  alias Tartarus.Clock
  alias TartarusWarehouse.{Distributor, Service}

  @doc false
  @impl true
  def init(args) do
    s =
      Map.merge(
        %{validate: false, continue: false},
        Map.merge(args, %{
          d:
            Distributor.new(args.world,
              continue: Map.get(args, :continue, false),
              max_pending_tasks: Map.get(args, :max_pending_tasks, :infinity)
            ),
          svc: Service.new(Map.get(args, :service_ms, 0)),
          released: 0,
          reissued: 0,
          specs: %{},
          # effects decided and checkpointed, not yet carried out
          effects: [],
          nonces: %{},
          last: %{}
        })
      )

    {:stay, s}
  end

  @doc false
  @impl true
  # Restored after a restart of the host: carry out what was decided and not yet done. A
  # sequence agent released before the restart may have died with the host before it
  # reached every robot, so the changes so far go round once more (robots ignore what
  # they already applied).
  def handle_arrival(%{restarts: n}, %{validate: false} = s) when n > 0 do
    # Restarted from the snapshot it arrived with: without a journal that is its first
    # state, and every job it had is forgotten. It says so rather than go on as if nothing
    # happened; its owner (the floor) stops accepting work.
    tell_owner(s, {:warehouse_distributor_failed, "the distributor crashed and lost its jobs"})
    {:stay, s}
  end

  def handle_arrival(_ctx, s) do
    if s.effects != [], do: send(self(), :effects)
    # Messages waiting for their service when the host went down: wake up for them again.
    s = %{s | svc: %{s.svc | armed: false}}
    if not :queue.is_empty(s.svc.queue), do: send(self(), :service_due)
    s = if s.d.changes != [], do: act({:sequence, s.d.changes}, s), else: s
    {:stay, s}
  end

  @doc false
  @impl true
  # Every message but :status waits for its service (see "Service time").
  def handle_message(:status, from, s), do: handle(:status, from, s)
  def handle_message(message, from, s), do: charge({message, from}, s)

  # No service time: handled at once, and not logged (nothing to measure).
  defp charge(item, %{svc: %{service_us: 0}} = s), do: serve(item, s)

  defp charge(item, s), do: {:stay, %{s | svc: Service.charge(s.svc, item)}}

  # A request whose handling raises is answered `{:error, message}` and changes nothing
  # (the distributor is pure until `later/2` returns): a bad message never takes the
  # distributor, and the jobs it holds, down. The owner hears of it too.
  defp serve({message, from}, s) do
    handle(message, from, s)
  catch
    kind, reason ->
      error =
        "the distributor could not handle #{inspect(message, limit: 5)}: " <>
          Exception.format_banner(kind, reason, __STACKTRACE__)

      if from, do: Tartarus.Agent.reply(from, {:error, error})
      tell_owner(s, {:warehouse_distributor_error, error})
      {:stay, s}
  end

  defp handle({:submit, spec}, from, s) when not is_map(spec),
    do: later(s, [{:reply, from, TartarusWarehouse.Job.plan(spec, s.d.world)}])

  defp handle({:submit, spec}, from, s) do
    id = Map.get(spec, :id)
    # A hash of each spec accepted (not the spec: 1 word a job), to answer a repeated
    # submission (its answer lost with the host) as the first one was.
    hash = :erlang.phash2(spec)

    # An answer that changes nothing is given at once, with no checkpoint (an answer lost
    # with the host is asked again): a burst refused for a full queue costs no journal.
    cond do
      Map.get(s.specs, id) == hash ->
        Tartarus.Agent.reply(from, :ok)
        {:stay, s}

      true ->
        case Distributor.submit(s.d, spec) do
          {:ok, d, actions} ->
            later(%{s | d: d, specs: Map.put(s.specs, id, hash)}, [{:reply, from, :ok} | actions])

          {:error, message} ->
            Tartarus.Agent.reply(from, {:error, message})
            {:stay, s}
        end
    end
  end

  defp handle({:insert, after_task, spec}, from, s) do
    case Distributor.insert(s.d, after_task, spec) do
      {:ok, d, actions} -> later(%{s | d: d}, [{:reply, from, :ok} | actions])
      {:error, message} -> later(s, [{:reply, from, {:error, message}}])
    end
  end

  defp handle({:delete, name}, from, s) do
    case Distributor.delete(s.d, name) do
      {:ok, d, actions} -> later(%{s | d: d}, [{:reply, from, :ok} | actions])
      {:error, message} -> later(s, [{:reply, from, {:error, message}}])
    end
  end

  defp handle({:started, ref}, from, s) do
    {d, actions} = Distributor.started(s.d, ref)
    later(%{s | d: d}, [{:reply, from, :ok} | actions])
  end

  defp handle({:done, ref, key}, from, s) do
    case {Map.get(s.d.out, ref), Map.get(s.last, ref)} do
      {a, _} when a != nil and {a.job, a.seq, a.index} == key ->
        {d, actions} = Distributor.done(s.d, ref)

        {mine, others} =
          Enum.split_with(actions, fn
            {:reissue, ^ref, _} -> true
            {:retire, ^ref} -> true
            _ -> false
          end)

        answer =
          case mine do
            [{:reissue, _, a}] -> {:reissue, a}
            [{:retire, _}] -> :retire
          end

        s = if match?({:reissue, _}, answer), do: %{s | reissued: s.reissued + 1}, else: s
        # A retired agent's repeated report is answered :retire without its entry (below):
        # only agents still out keep one.
        s =
          if answer == :retire,
            do: %{s | d: d, last: Map.delete(s.last, ref), nonces: Map.delete(s.nonces, ref)},
            else: %{s | d: d, last: Map.put(s.last, ref, {key, answer})}

        later(s, [{:reply, from, answer} | others])

      # A report repeated (its answer was lost with the host): the same answer.
      {_, {^key, answer}} ->
        later(s, [{:reply, from, answer}])

      _ ->
        later(s, [{:reply, from, :retire}])
    end
  end

  defp handle({:still, ref}, from, s) do
    {d, actions} = Distributor.still(s.d, ref)
    {mine, others} = Enum.split_with(actions, &(&1 == {:retire, ref}))
    later(%{s | d: d}, [{:reply, from, if(mine == [], do: :stay, else: :retire)} | others])
  end

  defp handle({:progress, ref, key}, _from, s) do
    {d, actions} = Distributor.progress(s.d, ref, key)
    later(%{s | d: d}, actions)
  end

  defp handle({:valid, ref, nonce}, from, s) do
    Tartarus.Agent.reply(from, Map.get(s.nonces, ref) == nonce)
    {:stay, s}
  end

  defp handle(:status, from, s) do
    Tartarus.Agent.reply(from, %{
      waiting: Distributor.waiting(s.d),
      held: Distributor.held(s.d),
      pending_jobs: Distributor.pending_jobs(s.d),
      released: s.released,
      reissued: s.reissued,
      service_log: s.svc.log
    })

    {:stay, s}
  end

  defp handle(_other, _from, s), do: {:stay, s}

  @doc false
  @impl true
  def handle_info(:service_due, s) do
    {svc, items, wake} = Service.due(s.svc, Clock.monotonic_time(:microsecond))
    Service.arm(wake)

    s =
      Enum.reduce(items, %{s | svc: svc}, fn item, s ->
        {:stay, s} = serve(item, s)
        s
      end)

    {:stay, s}
  end

  def handle_info(:effects, %{effects: []} = s), do: {:stay, s}

  def handle_info(:effects, s) do
    s = Enum.reduce(s.effects, %{s | effects: []}, &act/2)
    if s.validate, do: Tartarus.Agent.checkpoint()
    {:stay, s}
  end

  def handle_info(_msg, s), do: {:stay, s}

  # The change is checkpointed when this callback returns; its effects follow.
  defp later(s, effects) do
    if s.validate, do: Tartarus.Agent.checkpoint()
    send(self(), :effects)
    {:stay, %{s | effects: s.effects ++ effects}}
  end

  defp act({:reply, from, answer}, s) do
    Tartarus.Agent.reply(from, answer)
    s
  end

  defp act({:release, ref, a}, s) do
    nonce = {Clock.system_time(:microsecond), :erlang.unique_integer([:positive])}

    args = %{
      ref: ref,
      nonce: nonce,
      a: a,
      distributor: {Tartarus.Agent.id(), Tartarus.Agent.host()},
      robots: s.robots,
      idle_ms: s.idle_ms,
      round: s.round,
      validate: s.validate,
      guide: Map.get(s, :guide),
      continue: s.continue,
      racks: Map.get(s, :racks, [])
    }

    {:ok, _} =
      Tartarus.create_mobile_agent(Tartarus.Agent.host(), TartarusWarehouse.TaskAgent, args,
        name: "task-#{ref}",
        seed: {s.seed, ref}
      )

    %{s | released: s.released + 1, nonces: Map.put(s.nonces, ref, nonce)}
  end

  defp act({:job_done, id}, s) do
    if s.owner, do: send(s.owner, {:warehouse_job_done, id, Clock.system_time(:microsecond)})
    s
  end

  defp act({:sequence, changes}, s) do
    {n, change} = List.last(changes)

    {:ok, _} =
      Tartarus.create_mobile_agent(
        Tartarus.Agent.host(),
        TartarusWarehouse.SequenceAgent,
        %{change: change, changes: changes, robots: s.robots, all: s.all_robots, owner: s.owner},
        seed: {s.seed, :sequence, n}
      )

    s
  end

  defp act({:retire, _ref}, s), do: s

  defp act({:reissue, _ref, _a}, s), do: s

  defp tell_owner(%{owner: owner}, message) when is_pid(owner), do: send(owner, message)
  defp tell_owner(_s, _message), do: :ok
end
