defmodule TartarusWarehouse.DistributorAgent do
  @moduledoc """
  The Job Distributor's process: a static agent on the distributor's host that runs the
  pure `TartarusWarehouse.Distributor` and carries out its actions: it creates task agents
  (`TartarusWarehouse.TaskAgent`) on its host, hands a returning agent its next
  assignment, and tells its owner `{:warehouse_job_done, job_id, time_us}` when a job
  completes.

  Requests it answers: `{:submit, job_spec}` (`:ok` or `{:error, message}`; jobs arrive
  at any time), `{:insert, after_task, task_spec}` and `{:delete, task}` (on-the-fly
  programming: it releases a `TartarusWarehouse.SequenceAgent`), `{:started, ref}`,
  `{:done, ref}` and `{:still, ref}` from task agents, `:status`.
  """
  use Tartarus.Agent

  alias TartarusWarehouse.Distributor

  @doc false
  @impl true
  def init(args) do
    {:stay, Map.merge(args, %{d: Distributor.new(args.world), released: 0, reissued: 0})}
  end

  @doc false
  @impl true
  def handle_message({:submit, spec}, from, s) do
    case Distributor.submit(s.d, spec) do
      {:ok, d, actions} ->
        Tartarus.Agent.reply(from, :ok)
        {:stay, perform(actions, %{s | d: d})}

      {:error, message} ->
        Tartarus.Agent.reply(from, {:error, message})
        {:stay, s}
    end
  end

  def handle_message({:started, ref}, from, s) do
    {d, actions} = Distributor.started(s.d, ref)
    Tartarus.Agent.reply(from, :ok)
    {:stay, perform(actions, %{s | d: d})}
  end

  def handle_message({:done, ref}, from, s) do
    {d, actions} = Distributor.done(s.d, ref)

    {mine, others} =
      Enum.split_with(actions, fn
        {:reissue, ^ref, _} -> true
        {:retire, ^ref} -> true
        _ -> false
      end)

    case mine do
      [{:reissue, _, a}] -> Tartarus.Agent.reply(from, {:reissue, a})
      [{:retire, _}] -> Tartarus.Agent.reply(from, :retire)
    end

    s = if match?([{:reissue, _, _}], mine), do: %{s | reissued: s.reissued + 1}, else: s
    {:stay, perform(others, %{s | d: d})}
  end

  def handle_message({:insert, after_task, spec}, from, s) do
    case Distributor.insert(s.d, after_task, spec) do
      {:ok, d, actions} ->
        Tartarus.Agent.reply(from, :ok)
        {:stay, perform(actions, %{s | d: d})}

      {:error, message} ->
        Tartarus.Agent.reply(from, {:error, message})
        {:stay, s}
    end
  end

  def handle_message({:delete, name}, from, s) do
    {:ok, d, actions} = Distributor.delete(s.d, name)
    Tartarus.Agent.reply(from, :ok)
    {:stay, perform(actions, %{s | d: d})}
  end

  def handle_message({:still, ref}, from, s) do
    {d, actions} = Distributor.still(s.d, ref)
    {mine, others} = Enum.split_with(actions, &(&1 == {:retire, ref}))
    Tartarus.Agent.reply(from, if(mine == [], do: :stay, else: :retire))
    {:stay, perform(others, %{s | d: d})}
  end

  def handle_message(:status, from, s) do
    Tartarus.Agent.reply(from, %{
      waiting: Distributor.waiting(s.d),
      held: Distributor.held(s.d),
      pending_jobs: Distributor.pending_jobs(s.d),
      released: s.released,
      reissued: s.reissued
    })

    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}

  defp perform(actions, s), do: Enum.reduce(actions, s, &act/2)

  defp act({:release, ref, a}, s) do
    args = %{
      ref: ref,
      a: a,
      distributor: {Tartarus.Agent.id(), Tartarus.Agent.host()},
      robots: s.robots,
      idle_ms: s.idle_ms,
      round: s.round
    }

    {:ok, _} =
      Tartarus.create_mobile_agent(Tartarus.Agent.host(), TartarusWarehouse.TaskAgent, args,
        name: "task-#{ref}",
        seed: {s.seed, ref}
      )

    %{s | released: s.released + 1}
  end

  defp act({:job_done, id}, s) do
    if s.owner, do: send(s.owner, {:warehouse_job_done, id, System.system_time(:microsecond)})
    s
  end

  defp act({:sequence, change}, s) do
    {:ok, _} =
      Tartarus.create_mobile_agent(
        Tartarus.Agent.host(),
        TartarusWarehouse.SequenceAgent,
        %{change: change, robots: s.robots, owner: s.owner},
        seed: {s.seed, :sequence, change}
      )

    s
  end

  defp act({:retire, _ref}, s), do: s
  defp act({:reissue, _ref, _a}, s), do: s
end
