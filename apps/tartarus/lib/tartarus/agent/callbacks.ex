defmodule Tartarus.Agent.Callbacks do
  @moduledoc false
  # Running an agent's callbacks in its process, within a budget (Tartarus.Agent.Server calls
  # run/3 for each callback).
  #
  # Each callback has a budget, the host option :callback_timeout (ms). Before a callback
  # this process arms Tartarus.Clock.start_timer(ms, warden, {:"$tartarus_overrun", self()}) and
  # records {tref, callback, ms, from} under @watchdog in its dictionary (from: the request
  # handle_message/3 answers, or nil); after it, it erases the entry and cancels the timer.
  # The host's warden (Tartarus.Host.Warden, which outlives the host's server) is the
  # watchdog: when the timer message arrives it reads this process's
  # dictionary and, if the same tref is still there (the callback has not returned; a forged
  # message cannot name it), stops the process with exit reason {:callback_timeout,
  # callback, ms} (:kill if it traps exits), then removes the agent (no restart: the same
  # callback would hang again). A callback that returns after its timer fired (cancel_timer
  # answers false) stops this process with the same reason, its result ignored. Either way
  # a waiting requester gets {ref, {:error, {:callback_timeout, :handle_message, ms}}}
  # (Tartarus.request/3 returns the error). The host hears only of overruns: the cost per
  # callback is one timer armed and cancelled (about 1.6 µs).
  #
  # The budget is the design's time (Tartarus.Clock): in virtual time a callback that waits
  # (a receive, Tartarus.Clock.sleep/1) overruns when its budget of virtual time has passed;
  # one that computes costs no time and never overruns (a callback that never returns holds
  # virtual time still, see Tartarus.Clock.Virtual).

  alias Tartarus.Clock

  @ctx :"$tartarus_envelope"
  @watchdog :"$tartarus_watchdog"

  @doc false
  # Runs callback `cb` with the agent's envelope in the process dictionary (so the functions
  # of Tartarus.Agent can read and change payload), catching crashes so they become exits
  # with a readable reason, within the host's callback budget (see the top of this module).
  def run(data, cb, fun) do
    dog = arm(data.host, cb)

    outcome =
      try do
        {:ok, raw(data, fun)}
      catch
        kind, reason -> {:error, {kind, reason, __STACKTRACE__}}
      end

    case {disarm(dog), outcome} do
      {:ok, {:ok, {result, data}}} -> {:ok, result, data}
      {:ok, {:error, reason}} -> {:error, reason, data}
      {overrun, _} -> {:error, overrun, data}
    end
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
        Process.put(@watchdog, dog)
        dog
    end
  end

  defp disarm(nil), do: :ok

  defp disarm({tref, cb, ms, from}) do
    Process.delete(@watchdog)

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
  # For the host's watchdog: {exit reason, traps exits?, requester} if `pid` is still in the
  # callback it armed the timer `tref` for, else nil.
  def overrun(pid, tref) when node(pid) == node() do
    case Process.info(pid, [:dictionary, :trap_exit]) do
      [dictionary: dict, trap_exit: trap?] ->
        case List.keyfind(dict, @watchdog, 0) do
          {_, {^tref, cb, ms, from}} -> {{:callback_timeout, cb, ms}, trap?, from}
          _ -> nil
        end

      nil ->
        nil
    end
  end

  def overrun(_pid, _tref), do: nil

  @doc false
  # `fun` with the agent's envelope in the process dictionary (no budget, no catching).
  def raw(data, fun) do
    Process.put(@ctx, data.env)
    result = fun.()
    {result, %{data | env: Process.get(@ctx)}}
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
