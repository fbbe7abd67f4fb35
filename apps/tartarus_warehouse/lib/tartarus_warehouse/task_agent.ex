defmodule TartarusWarehouse.TaskAgent do
  @moduledoc """
  A task agent (thesis Algorithm 3): it carries the programs of its block of tasks (as
  code), their resources and the state information, and it is the one token of those
  resources while it lives.

  It migrates conscientiously among robots (`TartarusWarehouse.Roam`); on each robot it
  tries to claim it (`TartarusWarehouse.Robot`: the robot must be in the state the agent
  looks for and idle). When the claim succeeds it hands the programs to the robot and
  **stays until the robot has run them** (the adaptive clock of §4.5.3), the robot goes to
  the next state, and the agent tells the distributor it is done: it is then re-issued for
  the next job (and migrates on) or retires (stops). When a round of robots finds no match
  it waits `idle_ms` before the next hop, so idle agents do not spin. (The floor never
  leaves them without a robot: the last robot in service, or the last reaching a
  resource, cannot retire; see `TartarusWarehouse.Floor.change/2`.)

  With `guide: span` (an integer) the agent whose robot goes on to a next block announces,
  as soon as the robot starts its block, the state the robot will be in afterwards: a
  signal field named after that state, `span` hops wide. An agent looking for a booked
  robot climbs such a field when its host has one, and at its source (the robot, still
  busy) it waits, listening to the robot: the robot's "finished" wakes it at once. Where
  no field has arrived yet it waits on a robot, watching for the field
  (`Tartarus.Agent.watch_signal/1`): its arrival wakes the agent, which does not poll (a
  look every 100 ms is only a safety net, and after 500 ms on a robot with no field at all
  it moves on blind). The field is announced a whole block
  before the robot is free, so the agent is usually there, waiting, when it is. (Beyond
  the thesis: the thesis's agents search blind, which costs hops in proportion to the
  robots.)

  With `validate: true` (a distributor that survives restarts) the agent asks the
  distributor, after claiming a robot and before running anything, whether it is the
  valid holder of its assignment (see `TartarusWarehouse.DistributorAgent`).

  With `continue: true` (the distributor's, see `TartarusWarehouse.Distributor`, "Agents
  that continue") an agent given a run of blocks serves them in order: after each it
  moves on to the next job's robot without returning to the distributor, telling it only,
  one way, when a sequence's last block ran; it reports `done` at the end of its run.

  The agent of an inserted task (on-the-fly programming) looks for robots in state
  `{:inserted, task, _}`, leaves them in the state they would have had, and asks the
  distributor after each fruitless round whether its task was deleted.
  """
  # A guided agent waiting on a robot looks again this often even if nothing woke it.
  @safety_ms 100
  # ... and gives up waiting on a robot no field reaches after this long.
  @give_up_ms 500

  use Tartarus.Agent

  alias Tartarus.Agent
  alias Tartarus.Clock

  @doc false
  @impl true
  def init(args) do
    Enum.each(args.a.tasks, &Agent.add_module(&1.program))
    {:move, strategy(args), Map.put(args, :misses, 0)}
  end

  @doc false
  @impl true
  def handle_arrival(_ctx, s) do
    a = s.a

    case Agent.write(:robot, {:claim, a.look_for, a.needs, Agent.id()}) do
      :ok ->
        if valid?(s) do
          case hand_code(s) do
            :ok ->
              run(s)

            {:error, reason} ->
              :ok = Agent.write(:robot, {:unclaim, Agent.id()})
              {:stop, {:shutdown, {:rack, reason}}, s}
          end
        else
          # A stale copy (created again after the distributor's restart): it runs nothing.
          :ok = Agent.write(:robot, {:unclaim, Agent.id()})
          {:stop, :normal, s}
        end

      {:error, _} ->
        roam(%{s | misses: s.misses + 1})
    end
  end

  # The claimed robot runs the block.
  defp run(%{a: a} = s) do
    :ok = Agent.subscribe(:robot)
    run = %{job: a.job, seq: a.seq, tasks: a.tasks, next: a.next}
    :ok = Agent.write(:robot, {:run, Agent.id(), run})
    guide(s)

    if a.index == 0 and not Map.get(a, :continued, false) and
         ask(s, {:started, s.ref}) == :unreachable,
       do: {:stop, {:shutdown, :distributor_unreachable}, s},
       else: {:stay, %{s | misses: 0}}
  end

  # With racks (`phi_agents`, §4.7.1): the code of each task goes to the rack of each of
  # its resources (`TartarusWarehouse.Rack.rack_for/2`), one request a rack, answered
  # before the robot runs anything. `:ok`, or `{:error, reason}` when a rack did not
  # answer (`:unreachable`) or refused the code.
  defp hand_code(%{racks: [_ | _] = racks} = s) do
    s.a.tasks
    |> Enum.flat_map(fn t ->
      for r <- t.resources, do: {TartarusWarehouse.Rack.rack_for(r, racks), {t.name, t.program}}
    end)
    |> Enum.group_by(&elem(&1, 0), &elem(&1, 1))
    |> Enum.sort()
    |> Enum.reduce_while(:ok, fn {rack, tasks}, :ok ->
      case request(rack, {:code, Agent.id(), Enum.uniq(tasks)}) do
        :ok -> {:cont, :ok}
        :unreachable -> {:halt, {:error, :unreachable}}
        {:error, reason} -> {:halt, {:error, reason}}
      end
    end)
  end

  defp hand_code(_s), do: :ok

  @doc false
  @impl true
  def handle_info({:plugin_event, :robot, {:finished, id, _reports}}, s) do
    cond do
      id == Agent.id() -> finished(s)
      # Waiting here for a field: this robot finished someone else's block, and may now be
      # in the state looked for (or have announced it): look again at once.
      Map.has_key?(s, :wait_timer) -> handle_arrival(%{}, unwait(s))
      true -> {:stay, s}
    end
  end

  def handle_info(:roam, s), do: {:move, strategy(s), s}
  # Waiting on a robot for a field: try this robot again first (it may be the one).
  def handle_info({:guided, ref}, %{wait_timer: ref} = s), do: handle_arrival(%{}, unwait(s))

  # The field it waits for changed on this host.
  def handle_info({:tartarus_signal, _host, {:warehouse_wait, _}}, %{wait_timer: _} = s),
    do: handle_arrival(%{}, unwait(s))

  def handle_info(_msg, s), do: {:stay, s}

  # Its robot ran its block: the next job. An agent that continues (a run of blocks, see
  # `TartarusWarehouse.Distributor`, "Agents that continue") goes on to the next job's
  # robot without asking: it only tells the distributor, one way, that a sequence's last
  # block ran.
  defp finished(%{a: %{follow: [next | rest]}} = s) do
    a = s.a

    if a.next == :free,
      do: Tartarus.cast(s.distributor, {:progress, s.ref, {a.job, a.seq, a.index}})

    {:move, strategy(s), %{s | a: Map.merge(next, %{follow: rest, continued: true}), misses: 0}}
  end

  defp finished(s) do
    case ask(s, {:done, s.ref, {s.a.job, s.a.seq, s.a.index}}) do
      {:reissue, a} ->
        Enum.each(a.tasks, &Agent.add_module(&1.program))
        {:move, strategy(s), %{s | a: a, misses: 0}}

      :retire ->
        {:stop, :normal, s}

      :unreachable ->
        {:stop, {:shutdown, :distributor_unreachable}, s}
    end
  end

  @doc false
  @impl true
  def handle_move_failed(_dest, _reason, _ctx, s) do
    Clock.send_after(self(), :roam, max(s.idle_ms, 1))
    {:stay, s}
  end

  # With `guide: span`, the state the robot will be in after this block is announced as a
  # signal field around it when the block starts
  # (`Tartarus.Signal`), which the agent of the next block climbs instead of searching blind.
  defp guide(%{guide: span, a: %{next: {_, _, _} = next}}) when is_integer(span),
    do:
      Agent.emit_signal({:warehouse_wait, next}, 100,
        span: span,
        decay: {:linear, 100 / (span + 1)}
      )

  defp guide(_s), do: :ok

  # Ends a wait for a field (a later tick of it is ignored).
  defp unwait(s), do: Map.delete(s, :wait_timer)

  defp roam(%{guide: span, a: %{look_for: {_, _, _} = state}} = s) when is_integer(span) do
    gradient = Agent.gradient({:warehouse_wait, state})
    here = Agent.signal({:warehouse_wait, state})

    cond do
      # At the field's source: the robot announced the state and is still running its block.
      here > 0 and Enum.all?(gradient, fn {_, v} -> v <= here end) ->
        wait(s, :source)

      map_size(gradient) > 0 ->
        {best, _} = Enum.max_by(gradient, &elem(&1, 1))
        {:move, best, s}

      # The field covers every robot: on a robot, no field means the robot it looks for is
      # not waiting yet.
      TartarusWarehouse.Roam.robot?(s.robots, Agent.host()) ->
        wait(s, :no_field)

      true ->
        blind(s)
    end
  end

  defp roam(s), do: blind(s)

  # Waits on this robot without polling: it listens to the robot (its finishing a block
  # wakes the agent at once) and watches the field it looks for (its arrival or change
  # here wakes it). The first time on a host it looks again at once, for a field that
  # arrived between its look and its watch; then only every @safety_ms ms. (The key holds
  # the process: an agent that left and came back is a new process, with a new
  # subscription and watch to make.) A backstop: an agent that has waited @give_up_ms on a
  # robot with no field at all moves on blind (a field that could not reach it must not
  # leave it waiting for ever).
  defp wait(s, why) do
    ref = make_ref()
    key = {Agent.host(), s.a.look_for, self()}
    now = Clock.monotonic_time(:millisecond)

    cond do
      Map.get(s, :watching) == key and why == :no_field and now - s.since > @give_up_ms ->
        {:move, strategy(s), Map.delete(s, :watching)}

      Map.get(s, :watching) == key ->
        Clock.send_after(self(), {:guided, ref}, @safety_ms)
        {:stay, Map.put(s, :wait_timer, ref)}

      Agent.subscribe(:robot) == :ok and
          Agent.watch_signal({:warehouse_wait, s.a.look_for}) == :ok ->
        send(self(), {:guided, ref})
        {:stay, s |> Map.merge(%{wait_timer: ref, watching: key, since: now})}

      # It could not listen (the robot or the node's signal process did not answer): it
      # looks again soon, and tries to listen again then.
      true ->
        Clock.send_after(self(), {:guided, ref}, max(s.idle_ms, 1))
        {:stay, Map.put(s, :wait_timer, ref)}
    end
  end

  defp blind(s) do
    cond do
      s.misses >= s.round and Map.get(s.a, :persistent, false) and retired?(s) ->
        {:stop, :normal, s}

      s.misses >= s.round and s.idle_ms > 0 ->
        Clock.send_after(self(), :roam, s.idle_ms)
        {:stay, %{s | misses: 0}}

      true ->
        {:move, strategy(s), s}
    end
  end

  # An inserted task's agent asks whether its task was deleted.
  defp retired?(s), do: ask(s, {:still, s.ref}) == :retire

  defp valid?(%{validate: true} = s), do: ask(s, {:valid, s.ref, s.nonce}) == true
  defp valid?(_s), do: true

  # A request to the distributor, asked again while it is unreachable (its host may be
  # restarting; its answers are the same when asked twice), for at most 8 s; then
  # `:unreachable` (the distributor is gone: the agent stops, its token with it).
  defp ask(s, message), do: request(s.distributor, message)

  # A request to a static agent (the distributor, a rack), asked again while it is
  # unreachable, for at most 8 s; then `:unreachable`.
  defp request(to, message, deadline \\ nil) do
    deadline = deadline || Clock.monotonic_time(:millisecond) + 8_000

    case Tartarus.request(to, message, 2_000) do
      {:ok, answer} ->
        answer

      {:error, reason} ->
        if Clock.monotonic_time(:millisecond) > deadline do
          _ = reason
          :unreachable
        else
          Clock.sleep(10)
          request(to, message, deadline)
        end
    end
  end

  defp strategy(s), do: {:strategy, TartarusWarehouse.Roam, s.robots}
end
