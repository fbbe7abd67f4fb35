defmodule Tartarus.Locator do
  @moduledoc false
  # Finding an agent and chasing it: every facade call that addresses an agent goes through
  # here. `locate/1` follows forwarding pointers from the host a reference names to the
  # agent's pid; the chase loops (`handoff/2`, `kill/1`, `deliver/4`, `control/2`) look again
  # when the agent moved before it took the request, at most @max_chase times, backing off
  # while it is caught in a hand-off. `deliver/4` follows a moving agent from process to
  # process without a limit (the hand-over of messages makes that safe); only searches
  # that start again count against @max_chase.

  import Bitwise, only: [<<<: 2]
  require Tartarus.Clock
  alias Tartarus.{Clock, Host, Ledger}

  @max_chase 64

  @doc false
  # Finds an agent's pid. Returns it with the reference normalized to `{id, host}`.
  @spec locate(term()) :: {:ok, pid(), {String.t(), Host.t()}} | {:error, term()}
  # With `:arriving_ok` (delivery), a copy still arriving is as good as a running one: it
  # keeps the messages it gets and handles them once it runs.
  def locate(agent, n \\ @max_chase, arriving \\ :wait)
  def locate(_agent, 0, _arriving), do: {:error, :too_many_hops}

  def locate(agent, n, arriving) do
    with {:ok, {a, host}} <- normalize(agent) do
      result =
        case Host.local(host) do
          {:ok, info} -> Ledger.locate(info, a)
          _ -> Host.call(host, {:locate, a})
        end

      case result do
        {:here, pid, id} -> {:ok, pid, {id, host}}
        {:moved, next} -> locate({a, next}, n - 1, arriving)
        {:arriving, pid} when arriving == :arriving_ok -> {:ok, pid, {a, host}}
        {:arriving, _pid} -> backoff(n) && locate({a, host}, n - 1, arriving)
        :not_found -> {:error, :not_found}
        error -> error
      end
    end
  end

  @doc false
  # A move or clone ordered from outside. Not a GenServer.call: the agent's process may end
  # before it answers (its move commits, or it moves on after starting a clone), and the
  # answer then comes from the agent's, or the clone's, new process.
  @spec handoff(term(), {:move | :clone, term()}) :: term()
  def handoff(agent, op), do: handoff(agent, op, @max_chase)

  defp handoff(_agent, _op, 0), do: {:error, :too_many_hops}

  defp handoff(agent, op, n) do
    with {:ok, pid, ref} <- locate(agent) do
      mref = Process.monitor(pid)
      send(pid, {:"$gen_call", {self(), mref}, op})

      Clock.receive do
        {^mref, {:error, :in_transit}} ->
          Process.demonitor(mref, [:flush])
          backoff(n)
          handoff(ref, op, n - 1)

        {^mref, reply} ->
          Process.demonitor(mref, [:flush])
          reply

        {:DOWN, ^mref, :process, _, reason} ->
          after_down(op, mref, reason, ref, n)
      after
        60_000 ->
          Process.demonitor(mref, [:flush])
          {:error, :timeout}
      end
    end
  end

  # This move committed (the exit names our request): the answer comes from the new process
  # once it runs; if its node dies first, the agent went down with it.
  defp after_down({:move, _}, mref, {:shutdown, {:migrated, new_pid, {_, tag}}}, _ref, _n)
       when tag == mref do
    new_ref = Process.monitor(new_pid)

    Clock.receive do
      {^mref, reply} ->
        Process.demonitor(new_ref, [:flush])
        reply

      {:DOWN, ^new_ref, :process, _, reason} ->
        reply_or(mref, {:error, {:destination_down, reason}})
    after
      60_000 ->
        Process.demonitor(new_ref, [:flush])
        {:error, :timeout}
    end
  end

  # The agent's process ended before it took our move: look for the agent again.
  defp after_down({:move, _} = op, _mref, _reason, ref, n), do: handoff(ref, op, n - 1)

  # A clone is never retried (that could make a second clone): if the agent took the
  # request, the answer still comes from the clone.
  defp after_down({:clone, _}, mref, reason, _ref, _n) do
    Clock.receive do
      {^mref, reply} -> reply
    after
      10_000 -> {:error, {:outcome_unknown, reason}}
    end
  end

  # The reply `tag` if it is in the mailbox already, else `default`.
  defp reply_or(tag, default) do
    receive do
      {^tag, reply} -> reply
    after
      0 -> default
    end
  end

  @doc false
  # Kills an agent wherever it is now.
  @spec kill(term()) :: :ok | {:error, term()}
  def kill(agent), do: kill(agent, @max_chase)

  defp kill(_agent, 0), do: {:error, :too_many_hops}

  defp kill(agent, n) do
    with {:ok, {a, host}} <- normalize(agent) do
      # The host answers once the agent is down, within its callback budget.
      case Host.call(host, {:kill, a}, :infinity) do
        {:killed, _id} -> :ok
        {:moved, next} -> kill({a, next}, n - 1)
        {:arriving, _pid} -> backoff(n) && kill({a, host}, n - 1)
        :not_found -> {:error, :not_found}
        error -> error
      end
    end
  end

  @doc false
  # Delivers a message (`:post`: `:ok` once taken; `:request`: `{:ok, reply}`). The message
  # follows the agent without a hop limit: it carries one tag through all its copies, and
  # when the process it was sent to ends having moved on (its exit names its successor) it
  # is sent again there; the agent takes each tag once and hands what it took and had not
  # handled to its successor (see "reaching a busy agent" in Tartarus.Agent.Server), so it
  # is handled and acknowledged once. A process that ended otherwise (gone before we
  # watched it, crashed, an aborted copy) makes the search start again, at most
  # @max_chase times in a row without the agent moving.
  #
  # `from` is the sending agent's host (`sender/0`) when an emulator installed a transport
  # on this node (Tartarus.Transport): a message between two hosts pays the transport's
  # delay once on the way there and once on the way back (the acknowledgement, or the reply).
  @spec deliver(term(), :post | :request, term(), timeout(), map() | nil) :: term()
  def deliver(agent, kind, msg, timeout, from \\ sender()) do
    deadline = if timeout == :infinity, do: :infinity, else: now() + timeout
    # The tag grows with every message this node sends: the agent takes a sender's messages
    # in the order of their tags, each once (see take?/1 in Tartarus.Agent.Server).
    tag = System.unique_integer([:monotonic, :positive])
    deliver(agent, {kind, msg, false}, tag, deadline, @max_chase, false, from)
  end

  @doc false
  # The calling agent's host when a transport is installed on this node, else nil: a node
  # that emulates nothing pays one :persistent_term read per message.
  @spec sender() :: map() | nil
  def sender do
    if Tartarus.Transport.installed() != nil, do: Tartarus.Agent.calling_host()
  end

  defp deliver(agent, km, tag, deadline, n, crashed, from \\ nil)

  defp deliver(_agent, _km, _tag, _deadline, 0, _crashed, _from),
    do: {:error, :too_many_hops}

  defp deliver(agent, km, tag, deadline, n, crashed, from) do
    with :ok <- in_time(deadline) do
      case locate(agent, @max_chase, :arriving_ok) do
        {:ok, pid, {_id, host} = ref} ->
          case link_latency(from, host) do
            0 ->
              follow(pid, km, ref, tag, deadline, n)

            ms ->
              Clock.sleep(ms)
              result = follow(pid, km, ref, tag, deadline, n)
              Clock.sleep(ms)
              result
          end

        # A crashed agent is registered again once its host restarted it.
        {:error, :not_found} when crashed ->
          backoff(n)
          deliver(agent, km, tag, deadline, n - 1, crashed, from)

        error ->
          error
      end
    end
  end

  defp link_latency(nil, _host), do: 0
  defp link_latency(%{ref: host}, host), do: 0

  defp link_latency(from, host) do
    case Tartarus.Transport.installed() do
      nil -> 0
      transport -> transport.message_delay(from, host)
    end
  end

  defp crash?(reason),
    do:
      reason not in [:noproc, :normal, :shutdown, :killed] and not match?({:shutdown, _}, reason)

  # `km` is {kind, msg, sent}: `sent` says whether a copy of the message went out before this
  # one (to a process that moved on with it, or ended): that copy may be with the agent
  # already, so a refusal of this one is no failure.
  defp follow(pid, {kind, msg, sent}, ref, tag, deadline, n) do
    mref = Process.monitor(pid)
    send(pid, {:"$tartarus_msg", {self(), tag}, kind, msg})
    km = {kind, msg, true}

    Clock.receive do
      {^tag, :delivered} when kind == :post ->
        Process.demonitor(mref, [:flush])
        :ok

      {^tag, :delivered} ->
        # A request: the agent is still watched, so that one that ends without answering
        # (its callback crashed, it stopped) is an error at once, not a time-out.
        await_reply(tag, mref, deadline)

      {^tag, {:failed, {:overloaded, _}}} when sent ->
        # Refused by an agent that holds too much while it hands off, but an earlier copy
        # may be among what it holds (handed over, then taken and acknowledged): the
        # refusal says nothing of that copy. Sent again a little later, until the deadline
        # (then the outcome is unknown: a time-out, never a failure that was delivered).
        Process.demonitor(mref, [:flush])
        Clock.sleep(min(10, remaining(deadline)))
        follow(pid, km, ref, tag, deadline, n)

      {^tag, {:failed, reason}} ->
        # Not taken: handling it crashed the agent (host option :durable), or the agent
        # refused it (over its bound while it hands off) and no copy went out before.
        Process.demonitor(mref, [:flush])
        {:error, reason}

      {^tag, :retry} ->
        # A paused copy with a full stash did not keep it: send it again a little later.
        Process.demonitor(mref, [:flush])
        Clock.sleep(min(2, remaining(deadline)))
        follow(pid, km, ref, tag, deadline, n)

      {:DOWN, ^mref, :process, _, {:shutdown, {:migrated, next, _}}} when is_pid(next) ->
        # Moved on, with our message (handed over) or without it (it came too late).
        follow(next, km, ref, tag, deadline, @max_chase)

      {:DOWN, ^mref, :process, _, reason} ->
        backoff(n)
        deliver(ref, km, tag, deadline, n - 1, crash?(reason))
    after
      remaining(deadline) ->
        Process.demonitor(mref, [:flush])
        {:error, :timeout}
    end
  end

  defp await_reply(tag, mref, deadline) do
    Clock.receive do
      {^tag, {:reply, value}} ->
        Process.demonitor(mref, [:flush])
        {:ok, value}

      {^tag, {:error, {:callback_timeout, _, _}} = error} ->
        Process.demonitor(mref, [:flush])
        error

      {:DOWN, ^mref, :process, _, {:shutdown, {:migrated, next, _}}} when is_pid(next) ->
        # It moved on with the request taken: the answer comes from its next process.
        await_reply(tag, Process.monitor(next), deadline)

      {:DOWN, ^mref, :process, _, reason} ->
        ended_without_reply(tag, reason, deadline)
    after
      remaining(deadline) ->
        Process.demonitor(mref, [:flush])
        {:error, :timeout}
    end
  end

  # The agent's process ended after it took the request, without moving on. An answer it
  # sent comes before its end (one sender, one order); a host that killed it for overrunning
  # its callback budget says so itself, so a kill waits a moment for that word.
  defp ended_without_reply(tag, reason, deadline) do
    grace = if reason == :killed, do: min(remaining(deadline), 200), else: 0

    Clock.receive do
      {^tag, {:reply, value}} -> {:ok, value}
      {^tag, {:error, _} = error} -> error
    after
      grace ->
        if crash?(reason),
          do: {:error, {:agent_crashed, reason}},
          else: {:error, {:agent_ended, reason}}
    end
  end

  defp in_time(:infinity), do: :ok
  defp in_time(deadline), do: if(now() < deadline, do: :ok, else: {:error, :timeout})

  defp now, do: Clock.monotonic_time(:millisecond)
  defp remaining(:infinity), do: :infinity
  defp remaining(deadline), do: max(deadline - now(), 0)

  @doc false
  # A control call to the agent's process (info, payload operations), following it.
  @spec control(term(), term()) :: term()
  def control(agent, op), do: control(agent, op, @max_chase)

  defp control(_agent, _op, 0), do: {:error, :too_many_hops}

  defp control(agent, op, n) do
    with {:ok, pid, ref} <- locate(agent) do
      try do
        GenServer.call(pid, op, 60_000)
      catch
        :exit, {:timeout, _} -> {:error, :timeout}
        :exit, _ -> control(ref, op, n - 1)
      else
        {:error, :in_transit} ->
          Clock.sleep(5)
          control(ref, op, n - 1)

        result ->
          result
      end
    end
  end

  # Between retries of an agent caught in a hand-off: 1, 2, 4 ... 200 ms, about 12 s in all
  # (a paused copy in doubt waits for the migration timeout, 5 s by default, then asks).
  defp backoff(n) do
    Clock.sleep(min(1 <<< min(max(@max_chase - n, 0), 8), 200))
    true
  end

  defp normalize({agent, host}) do
    with {:ok, host} <- resolve_host(host), do: {:ok, {agent, host}}
  end

  defp normalize(id) when is_binary(id) do
    case Tartarus.Locator.Walk.search(id) do
      {:ok, host} -> {:ok, {id, host}}
      :error -> {:error, :not_found}
    end
  end

  defp normalize(other), do: {:error, {:bad_agent_ref, other}}

  @doc false
  # The full address a host reference means here: a full address as it is; a short name,
  # this node's host of that name, else the neighbour of that name of this node's hosts
  # (`Tartarus.Host.resolve/2`: two such neighbours are ambiguous), else a host of this node
  # (which the caller finds missing).
  @spec resolve_host(term()) :: {:ok, Host.t()} | {:error, term()}
  def resolve_host(host) do
    cond do
      not Host.address?(host) ->
        {:error, {:unknown_host, host}}

      match?({_, _}, host) or match?({:ok, _}, Host.local(Host.address(host))) ->
        {:ok, Host.address(host)}

      true ->
        neighbours =
          for h <- Host.Starter.hosts(),
              {:ok, info} <- [Host.local(h)],
              n <- Ledger.neighbours(info),
              uniq: true,
              do: n

        Host.resolve(host, neighbours)
    end
  end
end
