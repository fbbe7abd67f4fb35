defmodule Tartarus.Fault do
  @moduledoc """
  Fault injection at named points of the migration protocol, for tests and chaos runs.

  A point does nothing unless a hook is installed for it on that node (a `:persistent_term`
  read, so an idle point costs next to nothing). Hooks:

    * `{:pause, pid}` - the process reaching the point sends `{:fault_paused, point, self(), info}`
      to `pid` and waits for `{:fault_continue, self()}` (kill or partition nodes meanwhile);
    * `{:transform, {module, function, args}}` - the point's value is replaced by
      `apply(module, function, [value | args])` (e.g. `{Tartarus.Fault, :skew_clock, [3_600_000_000]}`);
    * `{:once, hook}` - `hook`, then the point is cleared.

  Points:

    * `:outgoing` - the source's envelope just before `prepare` is sent (value: the envelope);
    * `:prepared` - the source got `prepared`, before it decides (value: the new pid);
    * `:committing` - the source decided to commit, before `commit` is sent (value: the new pid);
    * `:admitting` - the process admitting a prepare at the destination (`Tartarus.Host.Arrivals`) passed every check and is about to become the paused copy (value: the envelope);
    * `:reviving` - a host's server is about to start a paused copy again from a parked record (`Tartarus.Host.Parked`; value: `{mig, copy}`);
    * `:prepare_received` - the process admitting a `prepare` at the destination started, before any check
      (value: the whole message, as sent: e.g. to capture a sealed prepare and replay it).

  Link emulation (latency and loss) is not a fault point: see `Tartarus.Transport`.
  """

  @typedoc "A hook."
  @type hook :: {:pause, pid()} | {:transform, {module(), atom(), list()}} | {:once, hook()}

  @doc "Installs `hook` at `point` on this node."
  @spec install(atom(), hook()) :: :ok
  def install(point, hook), do: :persistent_term.put({__MODULE__, point}, hook)

  @doc "Removes the hook at `point` on this node."
  @spec clear(atom()) :: :ok
  def clear(point) do
    _ = :persistent_term.erase({__MODULE__, point})
    :ok
  end

  @doc "Releases a process paused at a point."
  @spec continue(pid()) :: :ok
  def continue(pid) do
    send(pid, {:fault_continue, pid})
    :ok
  end

  @doc false
  @spec point(atom(), term()) :: term()
  def point(name, value) do
    case :persistent_term.get({__MODULE__, name}, nil) do
      nil -> value
      hook -> run(name, hook, value)
    end
  end

  defp run(name, {:once, hook}, value) do
    clear(name)
    run(name, hook, value)
  end

  defp run(name, {:pause, pid}, value) do
    me = self()
    send(pid, {:fault_paused, name, me, value})

    receive do
      {:fault_continue, ^me} -> value
    end
  end

  defp run(_name, {:transform, {m, f, args}}, value), do: apply(m, f, [value | args])

  @doc "A transform for `:outgoing`: the source's clock reads `offset_us` off."
  @spec skew_clock(Tartarus.Envelope.t(), integer()) :: Tartarus.Envelope.t()
  def skew_clock(env, offset_us), do: %{env | departed_at: env.departed_at + offset_us}
end
