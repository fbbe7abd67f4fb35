defmodule Tartarus.Host.OnNode do
  @moduledoc false
  # What the facade reads and writes of a host, run on the host's own node: `run/3` calls
  # one of the functions below locally, or on the host's node with :erpc. Each takes the
  # host's full address first. Remote callers (other nodes, the tooling) call them through
  # `run/3`, or with `:erpc.call(node, Tartarus.Host.OnNode, fun, [host | args])`.

  alias Tartarus.{Host, Ledger}

  @doc false
  # Runs `fun(host, args...)` of this module for a host on this node, or remotely on the
  # host's node. A host that is gone (or whose node is) answers `{:error, {:unknown_host, host}}`.
  @spec run(term(), atom(), list()) :: term()
  def run(host, fun, args), do: Host.on_node(host, __MODULE__, fun, args)

  @doc false
  # Stops a host of this node: its tree (server, agents, plugins) goes down at once.
  def stop_host({name, _}) do
    case Registry.lookup(Tartarus.HostRegistry, {:host_sup, name}) do
      [{pid, _}] ->
        _ = DynamicSupervisor.terminate_child(Tartarus.Application.hosts(), pid)
        :ok

      [] ->
        {:error, {:unknown_host, Host.address(name)}}
    end
  end

  @doc false
  # A change of the host's links (`{:connect, other, props}` or `{:disconnect, other}`),
  # made by a caller on the host's own node.
  def link(host, request), do: Host.call(host, request)

  @doc false
  def neighbours(host), do: with({:ok, h} <- Host.local(host), do: Ledger.neighbours(h))

  @doc false
  def agents(host) do
    with {:ok, h} <- Host.local(host) do
      h
      |> Ledger.residents()
      |> Enum.map(fn {id, name, module, pid} ->
        %{id: id, name: name, module: module, pid: pid}
      end)
      |> Enum.sort_by(& &1.name)
    end
  end

  @status_keys [
    :host,
    :resident,
    :visits,
    :neighbours,
    :counts,
    :hops,
    :forwarding_pointers,
    :plugins,
    :journal
  ]

  @doc false
  def status_keys, do: @status_keys

  @doc false
  def status(host, keys \\ @status_keys) do
    with {:ok, h} <- Host.local(host), do: Map.new(keys, &{&1, status_of(h, &1)})
  end

  defp status_of(h, :host), do: h.ref
  defp status_of(h, :resident), do: Ledger.counter(h, :resident)
  defp status_of(h, :visits), do: Ledger.counter(h, :visits)
  defp status_of(h, :neighbours), do: Ledger.neighbours(h)
  defp status_of(h, :counts), do: Tartarus.Events.host_counts(h)
  defp status_of(h, :hops), do: hop_summary(Ledger.hop_times(h))
  defp status_of(h, :forwarding_pointers), do: length(Ledger.forwarding_pointers(h))
  defp status_of(h, :plugins), do: Tartarus.Plugin.list(elem(h.ref, 0))
  defp status_of(h, :journal), do: Tartarus.Host.Persistence.status(h)

  @doc false
  def hop_times(host), do: with({:ok, h} <- Host.local(host), do: Ledger.hop_times(h))

  @doc false
  def hop_stats(host),
    do: with({:ok, h} <- Host.local(host), do: hop_summary(Ledger.hop_times(h)))

  @doc false
  def store_get(host, key, default) do
    with {:ok, h} <- Host.local(host) do
      case :ets.lookup(h.store, key) do
        [{_, v}] -> v
        [] -> default
      end
    end
  end

  @doc false
  def store_put(host, key, value) do
    with {:ok, h} <- Host.local(host) do
      :ets.insert(h.store, {key, value})
      :ok
    end
  end

  @doc false
  def attach_plugin({host_name, _} = host, name, {module, opts})
      when is_atom(name) and is_atom(module) do
    with {:ok, _} <- Host.local(host),
         true <-
           (Code.ensure_loaded?(module) and function_exported?(module, :read, 2)) ||
             {:error, {:not_a_plugin, module}} do
      sup = Host.via(:plugins, host_name)

      case DynamicSupervisor.start_child(sup, {Tartarus.Plugin, {host_name, name, module, opts}}) do
        {:ok, _} -> :ok
        {:error, {:already_started, _}} -> {:error, {:already_attached, name}}
        {:error, reason} -> {:error, reason}
      end
    end
  end

  def attach_plugin(_host, name, spec), do: {:error, {:bad_plugin, name, spec}}

  @doc false
  def plugin_call(host, name, request), do: Tartarus.Plugin.call(host, name, request)

  @doc false
  def plugins(host),
    do: with({:ok, h} <- Host.local(host), do: Tartarus.Plugin.list(elem(h.ref, 0)))

  @doc false
  # True if an agent with this id is arriving at a host of this node.
  def arriving?(host, id) do
    case Host.local(host) do
      {:ok, h} -> Ledger.arriving?(h, id)
      _ -> false
    end
  end

  @doc false
  def hop_summary([]), do: %{count: 0, median_us: nil, p99_us: nil, mean_us: nil, max_us: nil}

  def hop_summary(times) do
    sorted = Enum.sort(times)
    n = length(sorted)

    %{
      count: n,
      median_us: Tartarus.Percentile.sorted(sorted, 0.5),
      p99_us: Tartarus.Percentile.sorted(sorted, 0.99),
      mean_us: Enum.sum(sorted) / n,
      max_us: List.last(sorted)
    }
  end
end
