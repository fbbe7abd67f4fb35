defmodule Tartarus.Host.Directory do
  @moduledoc false
  # Resolves host addresses `{name, node}` to the pid of the host's server.
  #
  # Local hosts are found in Tartarus.HostRegistry. Remote hosts are asked for once over
  # :erpc and cached in an ETS table owned by this process, which monitors every cached pid
  # and drops the entry when the host (or the connection to its node) goes down, so a
  # restarted host is found again. Host names are never turned into atoms here: remote data
  # creates no atoms.
  #
  # Anything this server does not expect (a junk message, cast or call, from any node) is
  # dropped and counted (Tartarus.Events.drop/3). A forged :DOWN is dropped (only the
  # monitors this server made count). If the server restarts, its table (a cache) goes with it.
  use GenServer

  @table __MODULE__
  @rpc_timeout 5_000

  def start_link(_), do: GenServer.start_link(__MODULE__, nil, name: __MODULE__)

  @doc false
  @spec whereis(Tartarus.host()) :: {:ok, pid()} | {:error, {:unknown_host, term()}}
  def whereis({name, node}) when node == node() do
    case Registry.lookup(Tartarus.HostRegistry, {:host, name}) do
      [{pid, _}] -> {:ok, pid}
      [] -> {:error, {:unknown_host, {name, node}}}
    end
  end

  def whereis({_name, node} = host) when is_atom(node) do
    case :ets.lookup(@table, host) do
      [{_, pid}] ->
        {:ok, pid}

      [] ->
        try do
          :erpc.call(node, __MODULE__, :whereis, [host], @rpc_timeout)
        catch
          _, _ -> {:error, {:unknown_host, host}}
        else
          {:ok, pid} ->
            GenServer.cast(__MODULE__, {:watch, host, pid})
            :ets.insert(@table, {host, pid})
            {:ok, pid}

          error ->
            error
        end
    end
  end

  def whereis(other), do: {:error, {:unknown_host, other}}

  @doc false
  # Forget a cached pid (used when a send to it failed).
  def forget(host), do: :ets.delete(@table, host)

  @impl true
  def init(nil) do
    :ets.new(@table, [:named_table, :public, :set, read_concurrency: true])
    {:ok, %{}}
  end

  @impl true
  def handle_call(msg, from, monitors) do
    Tartarus.Events.drop(__MODULE__, :call, msg)
    Tartarus.Events.reply(from, {:error, :unexpected_call})
    {:noreply, monitors}
  end

  @impl true
  def handle_cast({:watch, host, pid}, monitors) when is_pid(pid) do
    if Map.has_key?(monitors, pid) do
      {:noreply, monitors}
    else
      ref = Process.monitor(pid)
      {:noreply, Map.put(monitors, pid, {host, ref})}
    end
  end

  def handle_cast(msg, monitors) do
    Tartarus.Events.drop(__MODULE__, :cast, msg)
    {:noreply, monitors}
  end

  @impl true
  # Only the monitors this server made count: a forged :DOWN (unknown ref) is dropped.
  def handle_info({:DOWN, ref, :process, pid, _} = msg, monitors) do
    case monitors do
      %{^pid => {host, ^ref}} ->
        :ets.match_delete(@table, {host, pid})
        {:noreply, Map.delete(monitors, pid)}

      _ ->
        Tartarus.Events.drop(__MODULE__, :info, msg)
        {:noreply, monitors}
    end
  end

  # An agent ended elsewhere (Tartarus.Ledger.gone/2): passed on to the named host's server,
  # which drops its forwarding pointers to it. Checked here so junk goes no further.
  def handle_info({:"$tartarus_gone", host, id, name}, monitors)
      when (is_atom(host) or is_binary(host)) and is_binary(id) and byte_size(id) <= 64 and
             (is_nil(name) or (is_binary(name) and byte_size(name) <= 1024)) do
    with {:ok, pid} <- whereis({host, node()}), do: send(pid, {:"$tartarus_gone", id, name})
    {:noreply, monitors}
  end

  def handle_info(msg, monitors) do
    Tartarus.Events.drop(__MODULE__, :info, msg)
    {:noreply, monitors}
  end
end
