defmodule Tartarus.AgentTable do
  @moduledoc false
  # The node's table of resident agents: id -> {pid, host name, name, module}. Agents write
  # their own entries (on arrival and departure); host servers remove the entries of agents
  # that crash or are killed. A plain ETS table rather than a Registry: no link per agent and
  # no cleanup message per exit, which matters on the migration hot path.
  #
  # The table belongs to the application's own process (created by setup/0 from
  # Tartarus.Application.start/2), not to this server: the server can crash and restart
  # without the node forgetting its agents. The server only answers junk (it expects no
  # message at all) by dropping and counting it.
  use GenServer

  @table __MODULE__

  def start_link(_), do: GenServer.start_link(__MODULE__, nil, name: __MODULE__)

  # Creates the table (once per application start; see the note above).
  def setup do
    if :ets.whereis(@table) == :undefined do
      :ets.new(@table, [
        :named_table,
        :public,
        :set,
        read_concurrency: true,
        write_concurrency: true
      ])
    end

    :ok
  end

  @impl true
  def init(nil), do: {:ok, nil}

  @impl true
  def handle_call(msg, from, state) do
    Tartarus.Events.drop(__MODULE__, :call, msg)
    Tartarus.Events.reply(from, {:error, :unexpected_call})
    {:noreply, state}
  end

  @impl true
  def handle_cast(msg, state) do
    Tartarus.Events.drop(__MODULE__, :cast, msg)
    {:noreply, state}
  end

  @impl true
  def handle_info(msg, state) do
    Tartarus.Events.drop(__MODULE__, :info, msg)
    {:noreply, state}
  end

  # Registers `pid` as agent `id`. An entry of a dead process (not yet cleaned) is replaced.
  def register(id, pid, host_name, name, module) do
    entry = {id, pid, host_name, name, module}

    if :ets.insert_new(@table, entry) do
      :ok
    else
      case :ets.lookup(@table, id) do
        [{^id, other, _, _, _}] when other != pid ->
          if alive?(other) do
            {:error, {:duplicate_agent, id, other}}
          else
            :ets.insert(@table, entry)
            :ok
          end

        _ ->
          :ets.insert(@table, entry)
          :ok
      end
    end
  end

  # Removes `id` if it is still registered to `pid` at `host_name` as `name` and `module`
  # (one delete of exactly that entry).
  def unregister(id, pid, host_name, name, module),
    do: :ets.delete_object(@table, {id, pid, host_name, name, module})

  # Removes `id`'s entry if it names `pid`.
  def unregister_pid(id, pid), do: :ets.match_delete(@table, {id, pid, :_, :_, :_})

  # {:ok, pid, host_name} for a live agent of this node.
  def lookup(id) do
    case :ets.lookup(@table, id) do
      [{^id, pid, host_name, _name, _module}] ->
        if alive?(pid), do: {:ok, pid, host_name}, else: :error

      [] ->
        :error
    end
  end

  # {:ok, pid, host_name} for agent `id`'s entry, its process alive or not: a dead one's entry
  # stays while its host decides on a restart (Tartarus.Ledger.take_resident/2).
  def entry(id) do
    case :ets.lookup(@table, id) do
      [{^id, pid, host_name, _name, _module}] -> {:ok, pid, host_name}
      [] -> :error
    end
  end

  def count, do: :ets.info(@table, :size)

  # Every registered (resident) agent of this node whose process lives.
  def all do
    for {id, pid, host_name, name, module} <- :ets.tab2list(@table),
        alive?(pid),
        do: %{id: id, name: name, module: module, pid: pid, host: {host_name, node()}}
  end

  def running?(module), do: :ets.match(@table, {:_, :_, :_, :_, module}, 1) != :"$end_of_table"

  defp alive?(pid) when node(pid) == node(), do: Process.alive?(pid)
  defp alive?(_pid), do: true
end
