defmodule Tartarus.Agent.Callbacks do
  @moduledoc false
  # Running an agent's callbacks in its process, within a budget (Tartarus.Agent.Server calls
  # run/3 for each callback).
  #
  # Each callback has a budget, the host option :callback_timeout (ms). Before a callback
  # this process arms Tartarus.Clock.start_timer(ms, warden, {:"$tartarus_overrun", self()}) and
  # records {tref, callback, ms, from} in its host's ledger (Tartarus.Ledger.arm_watchdog/3;
  # from: the request handle_message/3 answers, or nil); after it, it removes the entry and
  # cancels the timer. The host's warden (Tartarus.Host.Warden, which outlives the host's
  # server) is the watchdog: when the timer message arrives it reads the entry (overrun/3,
  # one ledger lookup: nothing of the agent's process is copied) and, if the same tref is
  # still there (the callback has not returned; a forged message cannot name it), stops the
  # process with exit reason {:callback_timeout, callback, ms} (:kill if it traps exits),
  # then removes the agent (no restart: the same callback would hang again). A callback that
  # returns after its timer fired (cancel_timer answers false) stops this process with the
  # same reason, its result ignored. Either way a waiting requester gets
  # {ref, {:error, {:callback_timeout, :handle_message, ms}}} (Tartarus.request/3 returns the
  # error). The host hears only of overruns: the cost per callback is one timer armed and
  # cancelled and one ledger entry written and removed (about 2 µs).
  #
  # An entry left by a process killed inside a callback goes with its host server's handling
  # of its end (Tartarus.Host.Server), or with the warden's when it overran.
  #
  # The budget is the design's time (Tartarus.Clock): in virtual time a callback that waits
  # (a receive, Tartarus.Clock.sleep/1) overruns when its budget of virtual time has passed;
  # one that computes costs no time and never overruns (a callback that never returns holds
  # virtual time still, see Tartarus.Clock.Virtual).
  #
  # The agent's code reads its context (Tartarus.Agent.id/0 and friends) from the one
  # process-dictionary key Tartarus.Agent keeps while a callback runs (raw/2).

  alias Tartarus.{Clock, Ledger}

  @doc false
  # Runs callback `cb` with the agent's context (so the functions of Tartarus.Agent can read
  # and change payload), catching crashes so they become exits with a readable reason,
  # within the host's callback budget (see the top of this module).
  # {:ok, result, data, checkpoint?} | {:error, reason, data}.
  def run(data, cb, fun) do
    dog = arm(data.host, cb)

    outcome =
      try do
        {:ok, raw(data, fun)}
      catch
        kind, reason -> {:error, {kind, reason, __STACKTRACE__}}
      end

    case {disarm(data.host, dog), outcome} do
      {:ok, {:ok, {result, data, checkpoint?}}} -> {:ok, result, data, checkpoint?}
      {:ok, {:error, reason}} -> {:error, reason, abandoned(data)}
      {overrun, {:ok, {_result, data, _}}} -> {:error, overrun, data}
      {overrun, _} -> {:error, overrun, abandoned(data)}
    end
  end

  # A callback that crashed: its context goes; the processes it started still end with
  # this one (Tartarus.Agent.Server's terminate/3).
  defp abandoned(data) do
    if Tartarus.Agent.abandon_callback(), do: %{data | children: true}, else: data
  end

  # `cb` is the callback's name, or {:handle_message, from} for a message.
  defp arm(host, cb) do
    case Map.get(host.opts, :callback_timeout, :infinity) do
      :infinity ->
        nil

      ms ->
        {name, from} = with name when is_atom(name) <- cb, do: {name, nil}
        tref = Clock.start_timer(ms, host.warden, {:"$tartarus_overrun", self()})
        dog = {tref, name, ms, from}
        Ledger.arm_watchdog(host, self(), dog)
        dog
    end
  end

  defp disarm(_host, nil), do: :ok

  defp disarm(host, {tref, cb, ms, from}) do
    Ledger.disarm_watchdog(host, self())

    if Clock.cancel_timer(tref) do
      :ok
    else
      reason = {:callback_timeout, cb, ms}
      overran(from, reason)
      reason
    end
  end

  @doc false
  # Tells a requester that the callback handling its request overran (Tartarus.request/3).
  def overran({pid, ref}, reason) when is_pid(pid), do: send(pid, {ref, {:error, reason}})
  def overran(_from, _reason), do: :ok

  @doc false
  # For the host's watchdog: {exit reason, traps exits?, requester} if agent process `pid`
  # of `host` is still in the callback it armed the timer `tref` for, else nil. Reads the
  # ledger's entry and the process's trap_exit flag, not its dictionary.
  def overrun(host, pid, tref) when node(pid) == node() do
    with {^tref, cb, ms, from} <- Ledger.watchdog(host, pid),
         {:trap_exit, trap?} <- Process.info(pid, :trap_exit) do
      {{:callback_timeout, cb, ms}, trap?, from}
    else
      _ -> nil
    end
  end

  def overrun(_host, _pid, _tref), do: nil

  @doc false
  # `fun` with the agent's context (no budget, no catching): {result, data, checkpoint?}
  # (checkpoint?: the agent's code called Tartarus.Agent.checkpoint/0).
  def raw(data, fun) do
    {result, env, checkpoint?, children?} =
      Tartarus.Agent.run_callback(data.host, data.env, data.children, fun)

    {result, %{data | env: env, children: children?}, checkpoint?}
  end

  @doc false
  # A payload operation of the facade (Tartarus.add_payload/3 and friends), run by the agent.
  def payload_op({:add, key, value}), do: Tartarus.Agent.put_payload(key, value)
  def payload_op({:remove, key}), do: Tartarus.Agent.remove_payload(key)
  def payload_op({:shed, key}), do: Tartarus.Agent.shed_payload(key)
  def payload_op({:copy, key}), do: Tartarus.Agent.copy_payload(key)
  def payload_op({:add_module, mod}), do: Tartarus.Agent.add_module(mod)
  def payload_op(:get), do: {:ok, Tartarus.Agent.payload()}
end
