defmodule Tartarus.Clock.Virtual do
  @moduledoc """
  The virtual clock of `Tartarus.Clock`: time that is the emulated network's, not the
  machine's. An emulator installs it for a network that runs in one VM (`install/1`), runs
  the network, and removes it (`uninstall/0`); `run/2` does the three around a function.

  ## Semantics

    * **Time stands still while anything runs.** The clock's process (the *advancer*) moves
      time only when the VM is idle: no process or port of the VM is runnable or running but
      itself, and none ran between two readings of the VM's reduction counters. Then it takes
      the earliest timer, sets the time to its due instant (time never goes back), and fires
      it. A computation therefore costs no virtual time, however long it runs: a design that
      wants it to cost time says so (`Tartarus.Clock.sleep/1`).
    * **One timer at a time.** Timers due at the same instant fire one by one, each once the
      VM went idle after the previous one, in an order drawn from the seed (a hash of the seed
      and the order they were armed in). With the same seed, the same program arms the same
      timers in the same order, so a run is replayed exactly, whatever else the machine is
      doing.
    * **Idle with no timer** is a network that waits for the outside (a test's next call, a
      message from a real node): the advancer polls every millisecond of real time.

  ## What it cannot represent

    * Work outside the VM's processes: a port or a NIF that waits on the operating system
      (a file read is a NIF call and runs; a socket's answer arriving later does not hold the
      time), console output included (a process waiting for its `IO.puts` to be written
      looks idle): a run in virtual time should print nothing while it runs (the mix tasks'
      `--json` and the sweeps' quiet mode do so). Modules are loaded at `install/1` for the
      same reason (a module loaded on first use is a wait on the file system). Networks of
      real BEAM nodes (`:peer`, network namespaces) run in real time.
    * Real-time timers that bypass `Tartarus.Clock` (the BEAM's own `after`, gen_statem's
      timeouts, `GenServer.call/3`'s timeout): they fire in real time, and time may jump past
      them. `scripts/check-clock` keeps them out of `apps/*/lib` but for the allowed ones.
    * Any process that never goes idle (a busy loop outside the emulation) holds the time
      forever.

  One virtual clock per VM: installing it switches every caller of `Tartarus.Clock` in the
  VM, so install it before the network starts and remove it after it stopped (a timer armed
  in one mode is unknown to the other).
  """

  use GenServer

  @typedoc "Options of `install/1`."
  @type option :: {:seed, integer()} | {:start_us, integer()} | {:strict, boolean()}

  @doc """
  Installs the virtual clock in this VM and starts its advancer (linked to the caller).

  Options: `:seed` (integer, default 0: the order of timers due at one instant),
  `:start_us` (the virtual monotonic time to start at, µs; default 0: the same on every run,
  so that whatever rounds the time to a grid rounds it alike; time read before the install
  is not comparable with time read after it), `:strict` (default false: also check every
  idle reading against the status of every process of the VM before firing, and count the
  readings it refutes in `stats/0`'s `:false_idles`; slow, for tests and diagnosis).

  Returns `{:ok, pid}`, or `{:error, :already_installed}`.
  """
  @spec install([option()]) :: {:ok, pid()} | {:error, :already_installed}
  def install(opts \\ []) do
    if Tartarus.Clock.virtual?() do
      {:error, :already_installed}
    else
      GenServer.start_link(__MODULE__, opts)
    end
  end

  @doc "Removes the virtual clock (pending timers are dropped); `:ok` if none was installed."
  @spec uninstall() :: :ok
  def uninstall do
    case :persistent_term.get({__MODULE__, :advancer}, nil) do
      pid when is_pid(pid) ->
        try do
          GenServer.stop(pid, :normal, 10_000)
        catch
          :exit, _ -> clear()
        end

      nil ->
        clear()
    end

    :ok
  end

  @doc """
  Runs `fun` with the virtual clock installed (options as `install/1`) and removes it after,
  whatever `fun` did. Returns what `fun` returned.
  """
  @spec run([option()], (() -> result)) :: result when result: term()
  def run(opts \\ [], fun) when is_function(fun, 0) do
    {:ok, _} = install(opts)

    try do
      fun.()
    after
      uninstall()
    end
  end

  @doc """
  Runs `fun` in `time`: `:virtual` installs the clock around it (with `seed`) unless one is
  installed already (a run inside a sweep that installed it); `:real` just runs it. The one
  entry of the emulator's runners.
  """
  @spec within(:real | :virtual, integer(), (() -> result)) :: result when result: term()
  def within(:virtual, seed, fun) do
    if Tartarus.Clock.virtual?(), do: fun.(), else: run([seed: seed], fun)
  end

  def within(:real, _seed, fun), do: fun.()

  @doc """
  What the advancer did so far: `:fired` timers, `:virtual_ms` since the install, `:wall_ms`
  since the install, `:pending` timers, `:idle_checks`, `:false_idles` (idle readings that
  the `:strict` check refuted; 0 without it), `:dirty_overlaps` (readings that saw a heap
  collected on a dirty CPU scheduler while another process was runnable: the two then run
  side by side and the run may not replay exactly; 0 is the witness that it does). Nil in
  real mode.
  """
  @spec stats() :: map() | nil
  def stats do
    case :persistent_term.get({__MODULE__, :advancer}, nil) do
      pid when is_pid(pid) -> GenServer.call(pid, :stats)
      nil -> nil
    end
  end

  # -- the advancer --------------------------------------------------------------------

  @impl true
  def init(opts) do
    preload()
    # One scheduler: the order in which processes run is then the program's, not the
    # machine's (see idle?/1), and the same seed gives the same run.
    schedulers = :erlang.system_flag(:schedulers_online, 1)
    :persistent_term.put({__MODULE__, :schedulers}, schedulers)
    seed = Keyword.get(opts, :seed, 0)
    start_us = Keyword.get(opts, :start_us, 0)
    tab = :ets.new(__MODULE__, [:ordered_set, :public, write_concurrency: true])
    at = :atomics.new(4, signed: true)
    :atomics.put(at, 1, start_us)
    :atomics.put(at, 3, System.system_time(:microsecond) - start_us)
    :persistent_term.put({__MODULE__, :advancer}, self())
    :persistent_term.put(Tartarus.Clock.__key__(), {tab, at, seed})
    Process.flag(:trap_exit, true)
    send(self(), :advance)

    {:ok,
     %{
       tab: tab,
       at: at,
       start_us: start_us,
       wall0: System.monotonic_time(:millisecond),
       fired: 0,
       checks: 0,
       strict: Keyword.get(opts, :strict, false),
       false_idles: 0,
       dirty_overlaps: 0,
       calib: calibrate()
     }}
  end

  @impl true
  def handle_call(:stats, _from, s) do
    {:reply,
     %{
       fired: s.fired,
       virtual_ms: div(:atomics.get(s.at, 1) - s.start_us, 1000),
       wall_ms: System.monotonic_time(:millisecond) - s.wall0,
       pending: :ets.info(s.tab, :size),
       idle_checks: s.checks,
       false_idles: s.false_idles,
       dirty_overlaps: s.dirty_overlaps
     }, s}
  end

  @impl true
  def handle_info(:advance, s) do
    s = advance(s, 200)
    send(self(), :advance)
    {:noreply, s}
  end

  def handle_info({:EXIT, _pid, reason}, s), do: {:stop, reason, s}
  def handle_info(_other, s), do: {:noreply, s}

  @impl true
  def terminate(_reason, _s), do: clear()

  defp clear do
    case :persistent_term.get({__MODULE__, :schedulers}, nil) do
      n when is_integer(n) -> :erlang.system_flag(:schedulers_online, n)
      nil -> :ok
    end

    _ = :persistent_term.erase({__MODULE__, :schedulers})
    _ = :persistent_term.erase(Tartarus.Clock.__key__())
    _ = :persistent_term.erase({__MODULE__, :advancer})
    :ok
  end

  # Up to `n` rounds of "wait for idle, fire the earliest timer", then back to the mailbox
  # (stats, stop). Waiting spins with yields (the VM's work runs meanwhile) and sleeps 1 ms
  # of real time when nothing is due (this is the clock itself: its one real timer).
  defp advance(s, 0), do: s

  defp advance(s, n) do
    s = %{s | checks: s.checks + 1}

    cond do
      not idle?(s.calib) ->
        s = if dirty_overlap?(), do: %{s | dirty_overlaps: s.dirty_overlaps + 1}, else: s
        :erlang.yield()
        advance(s, n - 1)

      s.strict and busy?() ->
        :erlang.yield()
        advance(%{s | false_idles: s.false_idles + 1}, n - 1)

      true ->
        case :ets.first(s.tab) do
          :"$end_of_table" ->
            # credo:disable-for-next-line
            receive do
            after
              1 -> s
            end

          key ->
            fire(s, key)
            advance(%{s | fired: s.fired + 1}, n - 1)
        end
    end
  end

  defp fire(s, {due, _rank, seq} = key) do
    case :ets.take(s.tab, key) do
      [{_, dest, what}] ->
        # A timer of a process that ended is dropped without moving the time (the BEAM
        # cancels a dead process's own timers too).
        if alive?(dest) do
          if due > :atomics.get(s.at, 1), do: :atomics.put(s.at, 1, due)
          deliver(dest, what, due, seq)
        end

      [] ->
        :ok
    end
  end

  # The ground truth behind idle?/1, for `strict: true`: some process but this one is not
  # waiting (O(processes): a check, not the clock's way).
  defp busy? do
    me = self()

    Enum.any?(Process.list(), fn p ->
      p != me and Process.info(p, :status) not in [nil, {:status, :waiting}]
    end)
  end

  # A process's heap collected on a dirty CPU scheduler while another process waits to run on
  # the normal one: the two run side by side, so the order of what they do next is the
  # machine's. Seen from the clock's own readings (it runs, so one normal task is itself):
  # active tasks per run queue are the normal queues, then the dirty CPU and IO queues.
  defp dirty_overlap? do
    [_dirty_io, dirty_cpu | normal] = Enum.reverse(:erlang.statistics(:active_tasks_all))
    dirty_cpu > 0 and Enum.sum(normal) > 1
  end

  defp alive?(pid) when is_pid(pid) and node(pid) == node(), do: Process.alive?(pid)
  defp alive?(name) when is_atom(name), do: Process.whereis(name) != nil
  defp alive?(_), do: true

  defp deliver(dest, what, due, seq) do
    msg =
      case what do
        {:send, msg} -> msg
        {:timeout, msg} -> {:timeout, {:"$tartarus_clock", due, seq}, msg}
      end

    send(dest, msg)
  rescue
    ArgumentError -> :ok
  end

  # Idle: this process is the only one runnable or running (processes, ports, dirty work),
  # and nothing else ran between two readings of the VM's reductions. The readings cost this
  # process a fixed number of reductions that the VM's count sees and its own does not (or
  # the other way round): `calib`, the most frequent difference in a quiet VM.
  # The VM runs on one scheduler while the clock is installed (init/1). Idle: twice in a
  # row, nothing but this process ran across a yield (the VM's reductions grew by this
  # process's own, `calib` being the readings' fixed difference), no run queue (dirty ones
  # included) holds a process, and the VM's active tasks, counted per run queue, are this
  # process alone. The last reading is the one that sees a process whose heap is collected
  # on a dirty CPU scheduler (heaps over about 1 MB are): it is in no run queue and runs
  # nothing a yield could let through, and the total counts (`total_active_tasks_all`
  # against `total_active_tasks`) do not tell it apart; such a reading let the time jump
  # while a central server sorted its queue (2026-12-06: the same seed gave two warehouse
  # runs). A yield alone is no proof either: on one scheduler it often returns at once.
  defp idle?(calib), do: quiet?(calib) and quiet?(calib)

  defp quiet?(calib) do
    delta = others()

    delta == calib and :erlang.statistics(:total_run_queue_lengths_all) == 0 and
      Enum.sum(:erlang.statistics(:active_tasks_all)) == 1
  end

  defp others do
    :erlang.yield()
    {:reductions, me0} = Process.info(self(), :reductions)
    {all0, _} = :erlang.statistics(:exact_reductions)
    :erlang.yield()
    {all1, _} = :erlang.statistics(:exact_reductions)
    {:reductions, me1} = Process.info(self(), :reductions)
    all1 - all0 - (me1 - me0)
  end

  # Every module of every loaded application, loaded now: a process that calls a module not
  # yet loaded waits for the code server, which reads the file meanwhile, and the VM would
  # look idle (the time would jump past the caller's timers).
  defp preload do
    for {app, _, _} <- Application.loaded_applications(),
        {:ok, modules} = :application.get_key(app, :modules),
        m <- modules,
        do: :code.ensure_loaded(m)

    :ok
  end

  defp calibrate, do: mode(&others/0, 200)

  defp mode(f, n) do
    {value, _} =
      1..n
      |> Enum.map(fn _ -> f.() end)
      |> Enum.frequencies()
      |> Enum.max_by(fn {_, k} -> k end)

    value
  end
end
