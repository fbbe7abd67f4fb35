defmodule TartarusWarehouse.Floor.Changes do
  @moduledoc """
  What a running floor is asked to do, and how: jobs submitted to its distributor, and
  the changes of `TartarusWarehouse.Floor.change/2` (and of `run/1`'s events) applied to
  the distributor, the robots or the distributor's host. A robot may leave only if the
  robots still in service reach every resource it reaches: the floor never takes jobs it
  has no robot for, and no task agent searches for a robot that will not come back.
  """

  alias Tartarus.Clock
  alias TartarusEmu.Network
  alias TartarusWarehouse.Job

  @doc """
  Submits a job to the distributor `dref` (a job already planned): `:ok`,
  `{:error, :queue_full}` (its bound of jobs accepted and not completed is reached) or
  `{:error, message}`. Asked again while the distributor is unreachable (its host
  restarting), for 30 s.
  """
  @spec submit({term(), term()}, map(), non_neg_integer()) ::
          :ok | {:error, :queue_full | String.t()}
  def submit(dref, job, tries \\ 3000) do
    case Tartarus.request(dref, {:submit, job}, 5_000) do
      {:ok, :ok} ->
        :ok

      {:ok, {:error, :queue_full}} ->
        {:error, :queue_full}

      # the distributor's refusal, as it says it
      {:ok, {:error, message}} when is_binary(message) ->
        {:error, message}

      {:error, _} when tries > 0 ->
        Clock.sleep(10)
        submit(dref, job, tries - 1)

      other ->
        {:error, "job #{inspect(job.id)} was refused: #{inspect(other)}"}
    end
  end

  @doc """
  Applies a change to a started floor (`ctx`, see `TartarusWarehouse.Floor.Build.start/3`):
  `{:insert, after_task, task}`, `{:delete, task}`, `{:retire, i}`, `{:join, i}` or
  `{:kill_distributor, down_ms}` (the distributor's host dies with everything on it and
  starts again `down_ms` later, on its journal if the floor has one), `{:disconnect,
  node}` or `{:reconnect, node}` (a robot or Σ node leaves the network or rejoins it:
  `TartarusEmu.Network.isolate/2`, `rejoin/2`). Every change is
  checked first (`TartarusWarehouse.Job.change/2`: the one door for changes), so a
  malformed one never reaches the distributor or a robot. `:ok`, or `{:error, reason}`
  when refused: nothing changed.
  """
  @spec apply_change(term(), TartarusWarehouse.Floor.Build.ctx()) :: :ok | {:error, String.t()}
  def apply_change(event, ctx)

  def apply_change({:insert, _, _}, %{design: :central}),
    do: {:error, "the central baseline takes no on-the-fly changes"}

  def apply_change({:delete, _}, %{design: :central}),
    do: {:error, "the central baseline takes no on-the-fly changes"}

  def apply_change(event, ctx) do
    case Job.change(event, ctx.world) do
      {:ok, event} -> apply_valid(event, ctx)
      {:error, message} -> {:error, message}
    end
  end

  defp apply_valid(event, %{dref: dref, robot_hosts: robot_hosts, net: net} = ctx) do
    result =
      case event do
        {:retire, i} -> retire(ctx, i)
        {:join, i} -> plugin(robot_hosts, i, :join)
        {:insert, after_task, task} -> Tartarus.request(dref, {:insert, after_task, task}, 30_000)
        {:delete, task} -> Tartarus.request(dref, {:delete, task}, 30_000)
        {:kill_distributor, down_ms} -> kill_distributor(net, down_ms)
        {:disconnect, node} -> leave(ctx, node, &Network.isolate/2)
        {:reconnect, node} -> leave(ctx, node, &Network.rejoin/2)
      end

    case result do
      ok when ok in [:ok, {:ok, :ok}] -> :ok
      {:ok, {:error, reason}} -> {:error, reason}
      {:error, :timeout} -> {:error, "the distributor did not answer within 30 s"}
      {:error, reason} when is_binary(reason) -> {:error, reason}
      {:error, reason} -> {:error, "#{inspect(event)} failed: #{inspect(reason)}"}
    end
  end

  # A robot may leave only if the robots still in service (not off, not retiring) reach
  # every resource it reaches: the floor never takes jobs it has no robot for, and no task
  # agent searches for a robot that will not come back.
  defp retire(ctx, i) do
    name = "r#{i}"

    with {:ok, host} <- robot_host(ctx.robot_hosts, i),
         {:ok, states} <- robot_states(ctx.robot_hosts),
         :ok <- still_served(ctx.world, states, name) do
      Tartarus.write_plugin(host, :robot, :retire)
    end
  end

  defp still_served(world, states, name) do
    in_service = fn r -> match?(%{off: false, retiring: false}, states[r]) end

    if in_service.(name) do
      others = for {r, reach} <- world.robots, r != name, in_service.(r), do: reach

      lost =
        MapSet.difference(world.robots[name], Enum.reduce(others, MapSet.new(), &MapSet.union/2))

      cond do
        others == [] ->
          {:error,
           "robot #{String.slice(name, 1..-1//1)} is the last robot in service: retiring it would leave the floor no robot to run jobs (let a standby robot join first)"}

        MapSet.size(lost) > 0 ->
          {:error,
           "robot #{String.slice(name, 1..-1//1)} is the last robot in service that reaches #{lost |> Enum.sort() |> Enum.map_join(", ", &inspect/1)}: retiring it would leave jobs that need it no robot"}

        true ->
          :ok
      end
    else
      # Already off or leaving: retiring it again changes nothing.
      :ok
    end
  end

  defp robot_states(robot_hosts) do
    Enum.reduce_while(robot_hosts, {:ok, %{}}, fn {name, host}, {:ok, acc} ->
      case Tartarus.read_plugin(host, :robot, :state) do
        {:ok, state} ->
          {:cont, {:ok, Map.put(acc, name, state)}}

        {:error, reason} ->
          {:halt,
           {:error, "robot #{name} could not be read (#{inspect(reason)}): nothing retired"}}
      end
    end)
  end

  # A robot or a Σ node leaves the network (every link of it down; what runs on it goes on)
  # or rejoins it (§4.3's MANET).
  defp leave(ctx, node, fun) do
    if node in Map.keys(ctx.net.hosts) and node != "jd",
      do: fun.(ctx.net, node),
      else: {:error, "no robot or secondary node #{inspect(node)} on this floor"}
  end

  # The distributor's host dies with everything on it, and starts again `down_ms` later
  # (on its journal, with `failover: true`).
  defp kill_distributor(net, down_ms) do
    :ok = Network.kill_node(net, "jd")
    Clock.sleep(down_ms)
    Network.restart_node(net, "jd")
  end

  defp plugin(robot_hosts, i, what) do
    with {:ok, host} <- robot_host(robot_hosts, i), do: Tartarus.write_plugin(host, :robot, what)
  end

  defp robot_host(robot_hosts, i) do
    case Map.fetch(robot_hosts, "r#{i}") do
      {:ok, host} -> {:ok, host}
      :error -> {:error, "no robot #{inspect(i)}"}
    end
  end
end
