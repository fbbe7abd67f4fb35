defmodule Tartarus.Clock do
  @moduledoc """
  The one clock of the platform and of everything that runs on it: the time now, timers,
  sleeps and the timeouts of `receive`. Every reading of time, every timer and every sleep
  under `apps/*/lib` goes through this module (`scripts/check-clock` lists any that does not,
  and the few allowed, each with its reason).

  ## Two modes

    * **Real** (the default, and the only mode of a deployed node or of a network of real BEAM
      nodes): each function is the BEAM's own (`System.monotonic_time/1`,
      `:erlang.send_after/3`, `Process.sleep/1`, ...) behind one `:persistent_term` read.
    * **Virtual** (`Tartarus.Clock.Virtual`, which an emulator installs for a network that
      runs in one VM): time stands still while anything in the VM runs, and jumps to the
      earliest timer once every process is idle (none runnable). CPU time is then never
      time: a computation takes no virtual time unless it says so (`sleep/1`). Timers due at
      the same instant fire one at a time, each after the VM went idle again, in an order
      drawn from the clock's seed, so that the same seed gives the same run.

  Readings: `monotonic_time/1` is the time to measure durations and arm deadlines with;
  `system_time/1` is the wall clock for timestamps (in virtual mode the wall clock of the
  moment the clock was installed, advanced by virtual time).

  Timers: `send_after/4` and `start_timer/3` return a timer (a reference in real mode, an
  opaque term in virtual mode: compare it, never inspect it), `cancel_timer/1` and
  `read_timer/1` take one. `sleep/1` suspends the caller. `receive/1` is `Kernel.SpecialForms.receive/1`
  whose `after` clause is a timer of this clock:

      require Tartarus.Clock

      Tartarus.Clock.receive do
        {:pong, x} -> {:ok, x}
      after
        5_000 -> :timeout
      end

  gen_statem's state timeouts and GenServer's `timeout` returns are the BEAM's own timers:
  code that must run in virtual time arms a timer of this clock instead (`start_timer/3`) and
  handles `{:timeout, timer, msg}`.

  What it does not cover: the timeout of a `GenServer.call/3` is a real-time safety net
  (a call answered at once in virtual time is answered at once in real time too); use
  `call/3` where a caller's wait must be the design's time.
  """

  @typedoc "A timer of this clock (a reference in real mode, an opaque term in virtual mode)."
  @type timer :: reference() | {:"$tartarus_clock", integer(), integer()}

  @typedoc "Where a timer's message goes (as `send/2` takes it)."
  @type dest :: pid() | atom() | {atom(), node()}

  import Bitwise, only: [<<<: 2]

  @key {__MODULE__, :virtual}

  @doc """
  The current mode: `:real` or `:virtual`.

      iex> Tartarus.Clock.mode()
      :real
  """
  @spec mode() :: :real | :virtual
  def mode, do: if(virtual() == nil, do: :real, else: :virtual)

  @doc "True when the virtual clock is installed in this VM."
  @spec virtual?() :: boolean()
  def virtual?, do: virtual() != nil

  @doc false
  # The virtual clock's handle ({table, atomics, seed}), or nil in real mode.
  @spec virtual() :: {:ets.tid(), :atomics.atomics_ref(), integer()} | nil
  def virtual, do: :persistent_term.get(@key, nil)

  @doc false
  def __key__, do: @key

  @doc """
  Monotonic time in `unit` (as `System.monotonic_time/1`): for durations and deadlines.

      iex> a = Tartarus.Clock.monotonic_time(:millisecond)
      iex> Tartarus.Clock.monotonic_time(:millisecond) >= a
      true
  """
  @spec monotonic_time(System.time_unit()) :: integer()
  def monotonic_time(unit \\ :native) do
    case virtual() do
      nil -> System.monotonic_time(unit)
      {_tab, at, _seed} -> System.convert_time_unit(:atomics.get(at, 1), :microsecond, unit)
    end
  end

  @doc """
  Wall-clock time in `unit` since the Unix epoch (as `System.system_time/1`): for timestamps.
  In virtual mode: the wall clock when the clock was installed plus the virtual time since.
  """
  @spec system_time(System.time_unit()) :: integer()
  def system_time(unit \\ :native) do
    case virtual() do
      nil ->
        System.system_time(unit)

      {_tab, at, _seed} ->
        System.convert_time_unit(:atomics.get(at, 1) + :atomics.get(at, 3), :microsecond, unit)
    end
  end

  @doc """
  Sends `msg` to `dest` after `time` ms (as `Process.send_after/4`; `abs: true` makes `time`
  a point of `monotonic_time(:millisecond)`). Returns the timer.

      iex> t = Tartarus.Clock.send_after(self(), :ding, 10)
      iex> receive do :ding -> :ok end
      :ok
      iex> Tartarus.Clock.cancel_timer(t)
      false
  """
  @spec send_after(dest(), term(), non_neg_integer(), keyword()) :: timer()
  def send_after(dest, msg, time, opts \\ []) do
    case virtual() do
      nil -> Process.send_after(dest, msg, time, opts)
      v -> arm(v, due(v, time, opts), dest, {:send, msg})
    end
  end

  @doc """
  Arms a timer that sends `{:timeout, timer, msg}` to `dest` after `time` ms (as
  `:erlang.start_timer/3`); the timer is the one returned.
  """
  @spec start_timer(non_neg_integer(), dest(), term()) :: timer()
  def start_timer(time, dest, msg) do
    case virtual() do
      nil -> :erlang.start_timer(time, dest, msg)
      v -> arm(v, due(v, time, []), dest, {:timeout, msg})
    end
  end

  @doc """
  Cancels `timer`: the ms it had left, or false when it had fired, was cancelled or is not
  a timer of the current mode (as `Process.cancel_timer/1`; a message already sent stays in
  the mailbox).
  """
  @spec cancel_timer(timer()) :: non_neg_integer() | false
  def cancel_timer(ref) when is_reference(ref), do: Process.cancel_timer(ref)

  def cancel_timer({:"$tartarus_clock", due, _seq} = t) do
    case virtual() do
      nil ->
        false

      {tab, at, _} = v ->
        case :ets.take(tab, key(v, t)) do
          [_] -> max(div(due - :atomics.get(at, 1), 1000), 0)
          [] -> false
        end
    end
  end

  def cancel_timer(_), do: false

  @doc "The ms `timer` has left, or false (as `Process.read_timer/1`)."
  @spec read_timer(timer()) :: non_neg_integer() | false
  def read_timer(ref) when is_reference(ref), do: Process.read_timer(ref)

  def read_timer({:"$tartarus_clock", due, _seq} = t) do
    case virtual() do
      nil ->
        false

      {tab, at, _} = v ->
        if :ets.member(tab, key(v, t)),
          do: max(div(due - :atomics.get(at, 1), 1000), 0),
          else: false
    end
  end

  def read_timer(_), do: false

  @doc """
  Suspends the caller for `ms` ms (as `Process.sleep/1`). In virtual mode the caller is idle
  meanwhile and the time passes only once everything else is idle too.
  """
  @spec sleep(timeout()) :: :ok
  def sleep(:infinity), do: Process.sleep(:infinity)

  def sleep(ms) when is_integer(ms) and ms >= 0 do
    case virtual() do
      nil ->
        Process.sleep(ms)

      v ->
        tag = make_ref()
        arm(v, due(v, ms, []), self(), {:send, {:"$tartarus_clock_sleep", tag}})

        receive do
          {:"$tartarus_clock_sleep", ^tag} -> :ok
        end
    end
  end

  @doc """
  The machine's monotonic time in `unit`, in either mode: for what measures the apparatus
  rather than the design (a run's `wall_ms`, a benchmark's rate, a progress line), never
  for the design's own time.
  """
  @spec machine_time(System.time_unit()) :: integer()
  def machine_time(unit \\ :native), do: System.monotonic_time(unit)

  @doc "The machine's wall clock in `unit`, in either mode (file names, provenance)."
  @spec machine_system_time(System.time_unit()) :: integer()
  def machine_system_time(unit \\ :native), do: System.system_time(unit)

  @doc """
  Sends `msg` to `dest` after `ms` ms of the machine's time, in either mode (a progress
  line's tick, a dashboard's refresh: what a person watches, not what the design does).
  """
  @spec machine_send_after(dest(), term(), non_neg_integer()) :: reference()
  def machine_send_after(dest, msg, ms), do: Process.send_after(dest, msg, ms)

  @doc "Sleeps `ms` ms of the machine's time, in either mode (see `machine_send_after/3`)."
  @spec machine_sleep(timeout()) :: :ok
  def machine_sleep(ms), do: Process.sleep(ms)

  @doc """
  `n` bytes for identities (agent ids): from the system's strong random source in real mode;
  in virtual mode drawn from the clock's seed and a counter, so that a run replayed with
  the same seed gets the same ids (maps keyed by them iterate in the same order, and so
  every choice made by walking one is the same).
  """
  @spec unique_bytes(pos_integer()) :: binary()
  def unique_bytes(n) do
    case virtual() do
      nil ->
        :crypto.strong_rand_bytes(n)

      {_tab, at, seed} ->
        k = :atomics.add_get(at, 4, 1)
        stream(seed, k, n, <<>>)
    end
  end

  defp stream(_seed, _k, n, acc) when byte_size(acc) >= n, do: binary_part(acc, 0, n)

  defp stream(seed, k, n, acc),
    do:
      stream(
        seed,
        k,
        n,
        acc <> :crypto.hash(:sha256, :erlang.term_to_binary({seed, k, byte_size(acc)}))
      )

  @doc """
  `GenServer.call/3` whose timeout is this clock's: in virtual mode the caller gives up
  after `timeout` ms of virtual time (a server on another node is called in real time).
  """
  @spec call(GenServer.server(), term(), timeout()) :: term()
  def call(server, request, timeout \\ 5_000) do
    if virtual() == nil or timeout == :infinity do
      GenServer.call(server, request, timeout)
    else
      case GenServer.whereis(server) do
        pid when is_pid(pid) and node(pid) == node() ->
          virtual_call(pid, server, request, timeout)

        _ ->
          GenServer.call(server, request, timeout)
      end
    end
  end

  defp virtual_call(pid, server, request, timeout) do
    mref = Process.monitor(pid)
    send(pid, {:"$gen_call", {self(), mref}, request})

    timer = send_after(self(), {:"$tartarus_clock_after", mref}, timeout)

    receive do
      {^mref, reply} ->
        __done__(timer, mref)
        Process.demonitor(mref, [:flush])
        reply

      {:DOWN, ^mref, _, _, reason} ->
        __done__(timer, mref)
        exit({reason, {GenServer, :call, [server, request, timeout]}})

      {:"$tartarus_clock_after", ^mref} ->
        Process.demonitor(mref, [:flush])
        exit({:timeout, {GenServer, :call, [server, request, timeout]}})
    end
  end

  @doc """
  `receive` whose `after` clause waits on this clock (see the moduledoc). Without an `after`
  clause, or with `after 0` or `after :infinity`, it is the plain `receive`.
  """
  defmacro receive(blocks) do
    clauses = Keyword.get(blocks, :do, [])

    case Keyword.get(blocks, :after) do
      nil ->
        quote do: receive(do: unquote(clauses))

      [{:->, _, [[timeout], after_body]}] ->
        timer = Macro.var(:clock_timer, __MODULE__)
        tag = Macro.var(:clock_tag, __MODULE__)
        t = Macro.var(:clock_timeout, __MODULE__)

        wrapped = __wrap__(clauses, Tartarus.Clock, timer, tag)

        timeout_clause =
          quote do
            {:"$tartarus_clock_after", ^unquote(tag)} -> unquote(after_body)
          end

        quote do
          unquote(t) = unquote(timeout)

          case Tartarus.Clock.__after__(unquote(t)) do
            :real ->
              receive do
                unquote(clauses)
              after
                unquote(t) -> unquote(after_body)
              end

            {unquote(timer), unquote(tag)} ->
              receive do
                unquote(timeout_clause ++ wrapped)
              end
          end
        end
    end
  end

  @doc false
  # For the receive macros (this module's, Tartarus.MachineClock's), at compile time: each
  # of the caller's clauses first calls `module.__done__(timer, tag)` (the timer goes),
  # then runs its body.
  def __wrap__(clauses, module, timer, tag) do
    Enum.map(List.wrap(clauses), fn {:->, meta, [args, body]} ->
      done = quote do: unquote(module).__done__(unquote(timer), unquote(tag))
      {:->, meta, [args, {:__block__, [], [done, body]}]}
    end)
  end

  @doc false
  # For receive/1: :real for a plain `after`, or the virtual timer and its tag.
  def __after__(t) when t == :infinity or t == 0, do: :real

  def __after__(t) when is_integer(t) and t > 0 do
    case virtual() do
      nil ->
        :real

      v ->
        tag = make_ref()
        {arm(v, due(v, t, []), self(), {:send, {:"$tartarus_clock_after", tag}}), tag}
    end
  end

  def __after__(t),
    do: raise(ArgumentError, "receive's after expects a timeout, got: #{inspect(t)}")

  @doc false
  # A clause other than the timeout matched: the timer goes, and its message if it came.
  def __done__(timer, tag) do
    if cancel_timer(timer) == false do
      receive do
        {:"$tartarus_clock_after", ^tag} -> :ok
      after
        0 -> :ok
      end
    end

    :ok
  end

  # -- the virtual backend's data plane (Tartarus.Clock.Virtual runs the time) ------------

  # Timers live in the virtual clock's ordered_set as {{due_us, rank, seq}, dest, what}: due
  # first, then a rank drawn from the seed and the arming sequence (a seeded order of the
  # timers due at one instant), then the sequence itself (unique). The atomics hold: 1 the
  # time now (µs), 2 the arming sequence, 3 the wall clock's offset (µs), 4 the count of
  # unique_bytes/1 draws.
  # An absolute time may be negative (the BEAM's monotonic time usually is).
  defp due({_tab, at, _}, time, opts) when is_integer(time) do
    cond do
      opts[:abs] -> time * 1000
      time >= 0 -> :atomics.get(at, 1) + time * 1000
      true -> raise ArgumentError, "expected a non-negative time in ms, got: #{time}"
    end
  end

  defp arm({tab, at, seed}, due_us, dest, what) do
    seq = :atomics.add_get(at, 2, 1)
    :ets.insert(tab, {{due_us, rank(seed, seq), seq}, dest, what})
    {:"$tartarus_clock", due_us, seq}
  end

  defp key({_tab, _at, seed}, {:"$tartarus_clock", due, seq}), do: {due, rank(seed, seq), seq}

  defp rank(seed, seq), do: :erlang.phash2({seed, seq}, 1 <<< 26)
end
