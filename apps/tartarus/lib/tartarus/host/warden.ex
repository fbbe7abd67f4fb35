defmodule Tartarus.Host.Warden do
  @moduledoc false
  # What of a host must outlive its server: the first child of the host's supervisor
  # (Tartarus.Host.Supervisor, :rest_for_one), so a server that dies (even by an untrappable
  # :kill) is restarted beside the same host, and its agents live on, adopted by the new
  # server (Tartarus.Host.Server's init).
  #
  # It owns:
  #   * the host's tables (ledger, store, acknowledgements), its counters, hop ring and
  #     incarnation: the host map the agents hold (Tartarus.Host.local/1) stays valid across
  #     a restart of the server, but for its :pid, which the agents never keep for later
  #     (they find the current server with Tartarus.Host.server/1);
  #   * the journal (Tartarus.Host.Persistence) and its writer, opened once: what it restored
  #     is handed to the first server that asks (take_restore/1), once;
  #   * the watchdog of the agents' callback budgets: each callback arms a timer to this
  #     process (Tartarus.Agent.Callbacks), so an agent's budget holds whatever becomes of
  #     the server; an overrun is written under {:overran, pid} in the ledger for the server
  #     that sees the agent go down.
  #
  # The server records each agent process it watches under {:proc, pid} in the ledger (a
  # local creator does too, before it asks the server to adopt the process): a new server
  # monitors them all, and when the host stops this process kills every one of them still
  # alive (also those a killed server left) and removes the host's entries from the node's
  # agent table.
  #
  # It expects nothing else: calls, casts and messages it does not know are dropped and
  # counted.
  use GenServer
  require Logger
  require Tartarus.Events

  alias Tartarus.Host

  @doc false
  def start_link({name, opts}),
    do: GenServer.start_link(__MODULE__, {name, opts}, name: Host.via(:warden, name))

  @doc false
  # The host map of host `name` (without :pid: the server adds its own).
  @spec host(Host.name()) :: map()
  def host(name), do: GenServer.call(Host.via(:warden, name), :host, :infinity)

  @doc false
  # What the journal held when the host started: {agents, in_doubt}, the first time it is
  # asked; {[], []} after that.
  @spec take_restore(Host.name()) :: {list(), list()}
  def take_restore(name), do: GenServer.call(Host.via(:warden, name), :take_restore, :infinity)

  @impl true
  def init({name, opts}) do
    Process.flag(:trap_exit, true)

    case Tartarus.Host.Persistence.open(name, opts[:data_dir]) do
      {:ok, journal, {agents, in_doubt, decided}} ->
        s = new_state(name, opts, journal, agents, in_doubt, decided)
        report_damage(s.host, journal)
        {:ok, s}

      {:error, reason} ->
        {:stop, reason}
    end
  end

  defp new_state(name, opts, journal, agents, in_doubt, decided) do
    store =
      :ets.new(:tartarus_store, [:set, :public, read_concurrency: true, write_concurrency: true])

    # Acknowledgements of arrived copies, by source host, until the next batch leaves.
    acks = :ets.new(:tartarus_acks, [:duplicate_bag, :public, write_concurrency: true])

    :ets.insert(store, Enum.to_list(opts[:store] || %{}))

    host = %{
      ref: {name, node()},
      warden: self(),
      # Migrations an earlier run of this host committed: answers for destinations in doubt.
      ledger: Tartarus.Ledger.new(decided),
      store: store,
      acks: acks,
      counters: Tartarus.Events.new_counters(),
      hops: Tartarus.Ledger.new_hop_ring(),
      # The host's tallies (residents, visits, agent processes, admissions under way).
      tally: Tartarus.Ledger.new_tally(),
      # Whether a flush of acknowledgements is armed (see Tartarus.Migration.Arrival).
      acks_armed: :atomics.new(1, []),
      # Tells this run of the host from earlier ones (in migration ids), see Ledger.decision/3.
      incarnation: :crypto.strong_rand_bytes(8),
      # What an admitting process (Tartarus.Host.Arrivals.admit/2) runs to become the paused
      # copy: given here, so that admission, which the migration's source calls, does not
      # depend on the agent process's module, which depends on the source.
      become: &Tartarus.Agent.Server.become/4,
      journal: journal,
      opts: Map.new(opts)
    }

    %{host: host, restore: {agents, in_doubt}}
  end

  # A journal that could not be read whole: said once, in an event, a warning and the
  # host's status (Tartarus.status/2, :journal).
  defp report_damage(host, %{damage: %{} = d} = journal) do
    bytes = Enum.reduce(d.ranges, 0, fn {_, n}, acc -> acc + n end)

    Tartarus.Events.emit(
      host,
      %{
        type: :journal_damaged,
        host: host.ref,
        path: journal.path,
        moved_to: d.moved_to,
        ranges: d.ranges,
        unreadable_bytes: bytes,
        records: d.records
      },
      journal_damaged: 1,
      journal_unreadable_bytes: bytes
    )

    Logger.error(
      "host #{inspect(host.ref)}: journal #{journal.path} could not be read whole: " <>
        "#{bytes} bytes unreadable at (offset, length) #{inspect(d.ranges, limit: 8)}; " <>
        "#{d.records} records restored; the original is kept as #{d.moved_to}"
    )
  end

  defp report_damage(_host, _journal), do: :ok

  @impl true
  def handle_call(_msg, from, s) when not Tartarus.Events.is_from(from), do: {:noreply, s}
  def handle_call(:host, _from, s), do: {:reply, s.host, s}

  def handle_call(:take_restore, _from, s),
    do: {:reply, s.restore, %{s | restore: {[], []}}}

  def handle_call(msg, from, s) do
    Tartarus.Events.drop(__MODULE__, :call, msg, s.host.ref)
    Tartarus.Events.reply(from, {:error, :unexpected_call})
    {:noreply, s}
  end

  @impl true
  def handle_cast(msg, s) do
    Tartarus.Events.drop(__MODULE__, :cast, msg, s.host.ref)
    {:noreply, s}
  end

  # The watchdog: an agent's callback budget ran out. Only a timer the agent armed for the
  # callback it is still in counts (Agent.Callbacks.overrun/3 reads the agent's entry in the
  # ledger).
  @impl true
  def handle_info({:timeout, tref, {:"$tartarus_overrun", pid}}, s) when is_pid(pid) do
    case Tartarus.Agent.Callbacks.overrun(s.host, pid, tref) do
      {reason, trap?, from} ->
        Tartarus.Ledger.disarm_watchdog(s.host, pid)
        # Read by the server when the agent is down (the exit reason of one that traps
        # exits is :kill: any other signal would reach its code as a message).
        Tartarus.Ledger.put_overrun(s.host, pid, reason)
        Process.exit(pid, if(trap?, do: :kill, else: reason))
        Tartarus.Agent.Callbacks.overran(from, reason)

      nil ->
        :ok
    end

    {:noreply, s}
  end

  # The journal's writer died: this host cannot keep its promises without it.
  def handle_info({:EXIT, pid, reason}, %{host: %{journal: %{io: pid}}} = s),
    do: {:stop, {:journal, reason}, s}

  def handle_info({:EXIT, _pid, _reason}, s), do: {:noreply, s}

  def handle_info(msg, s) do
    Tartarus.Events.drop(__MODULE__, :info, msg, s.host.ref)
    {:noreply, s}
  end

  # The host stops: every agent process it still has is killed (the server killed those it
  # watched already; these are the ones a killed server left, or that started meanwhile),
  # and the host's residents leave the node's agent table.
  @impl true
  def terminate(_reason, s) do
    Tartarus.Ledger.mark_stopping(s.host)
    kill_all(s.host)
    unregister_all(s.host)
    Tartarus.Host.Persistence.close(s.host.journal)
  catch
    _, _ -> :ok
  end

  @doc false
  # Kills every agent process recorded in `host`'s ledger (exit signal :kill: an agent that
  # traps exits must not hold up a stopping host).
  @spec kill_all(map()) :: :ok
  def kill_all(host) do
    for {pid, _entry} <- Tartarus.Ledger.procs(host), do: Process.exit(pid, :kill)
    :ok
  end

  # The node's agent table forgets this host's residents (their processes are being killed:
  # nobody will see them go down).
  defp unregister_all(%{ref: {name, _}} = host) do
    for {id, agent_name, module, pid} <- Tartarus.Ledger.residents(host),
        do: Tartarus.AgentTable.unregister(id, pid, name, agent_name, module)

    :ok
  end
end
