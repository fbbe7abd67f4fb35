defmodule TartarusWarehouse.Service do
  @moduledoc """
  The service time of a process that serves every robot (the central server, the Job
  Distributor): one FIFO server that takes `S` ms for each message it handles. A message
  that arrives at `t` is done at `max(t, the previous message's done) + S`, computed in µs
  (so the millisecond timers that wake the process do not add their rounding up), and is
  only then handled; the process sleeps meanwhile (no CPU, so it does not slow the robots'
  hosts on the same cores). With `S = 0` a message is handled at once (and not logged).

  The owning agent keeps the service in its state: `admit/4` when a message arrives (it
  returns the wake-up to arm, if any), `due/2` when that wake-up comes (the messages now
  done, to handle in order). Every message served is logged as `{arrived_us, started_us,
  done_us}` (µs of `Tartarus.Clock.monotonic_time/1`: in virtual time, the declared service
  time, not the machine's); `stats/3` and `timeline/4` read the log: the busy fraction
  (utilisation) and the queue length (messages waiting or in service) over time.

      iex> alias TartarusWarehouse.Service
      iex> s = Service.new(2.0)
      iex> {s, {:wake_at_ms, 3}} = Service.admit(s, :a, 1_000, false)
      iex> {s, nil} = Service.admit(s, :b, 1_500, false)
      iex> {s, items, {:wake_at_ms, 5}} = Service.due(s, 3_100)
      iex> {items, s.log}
      {[:a], [{1000, 1000, 3000}]}
      iex> {s, [:b], nil} = Service.due(s, 5_000)
      iex> Service.stats(s.log, 1_000, 5_000)
      %{busy: 1.0, messages: 2, mean_wait_ms: 0.75, max_queue: 2}
  """

  alias Tartarus.Clock

  @typedoc "A service: its time per message (µs), the queue, when it is next free, the log."
  @type t :: %{
          service_us: non_neg_integer(),
          free_at: integer() | nil,
          queue: :queue.queue(),
          armed: boolean(),
          log: [{integer(), integer(), integer()}]
        }

  @doc "A service taking `ms` (a number, ms) per message."
  @spec new(number()) :: t()
  def new(ms),
    do: %{
      service_us: round(ms * 1000),
      free_at: nil,
      queue: :queue.new(),
      armed: false,
      log: []
    }

  @doc """
  In the serving process: `item` arrives now (`admit/4`), and the wake-up it asks for is
  armed (`arm/1`). Returns the service.
  """
  @spec charge(t(), term()) :: t()
  def charge(s, item) do
    {s, wake} = admit(s, item, Clock.monotonic_time(:microsecond), false)
    arm(wake)
    s
  end

  @doc """
  In the serving process: arms the wake-up `admit/4` or `due/2` asked for, a
  `:service_due` message to this process at that ms of `Tartarus.Clock.monotonic_time/1`
  (a timer of `Tartarus.Clock`; nothing for nil).
  """
  @spec arm({:wake_at_ms, integer()} | nil) :: :ok
  def arm(nil), do: :ok

  def arm({:wake_at_ms, ms}) do
    Clock.send_after(self(), :service_due, ms, abs: true)
    :ok
  end

  @doc """
  A message (`item`) arrives at `now_us` (monotonic µs); `internal` marks a message the
  process sends itself (a command) rather than receives (it is served the same). Returns
  the service and `{:wake_at_ms, ms}` (a monotonic ms at which to call `due/2`) when the
  process must arm a wake-up, else nil.
  """
  @spec admit(t(), term(), integer(), boolean()) :: {t(), {:wake_at_ms, integer()} | nil}
  def admit(s, item, now_us, _internal) do
    # (monotonic time may be negative: nothing served yet is nil, not 0)
    start = if s.free_at, do: max(now_us, s.free_at), else: now_us
    done = start + s.service_us
    s = %{s | free_at: done, queue: :queue.in({item, {now_us, start, done}}, s.queue)}

    if s.armed, do: {s, nil}, else: {%{s | armed: true}, {:wake_at_ms, ceil_ms(done)}}
  end

  @doc """
  The wake-up came at `now_us`: the messages done by now (in order, to handle), and the
  next wake-up to arm (or nil).
  """
  @spec due(t(), integer()) :: {t(), [term()], {:wake_at_ms, integer()} | nil}
  def due(s, now_us), do: take(%{s | armed: false}, now_us, [])

  defp take(s, now_us, acc) do
    case :queue.peek(s.queue) do
      {:value, {item, {_, _, done} = times}} when done <= now_us ->
        take(%{s | queue: :queue.drop(s.queue), log: [times | s.log]}, now_us, [item | acc])

      {:value, {_, {_, _, done}}} ->
        {%{s | armed: true}, Enum.reverse(acc), {:wake_at_ms, ceil_ms(done)}}

      :empty ->
        {s, Enum.reverse(acc), nil}
    end
  end

  defp ceil_ms(us), do: div(us + 999, 1000)

  @doc """
  Over the window `[from_us, to_us]` of a log (`{arrived, started, done}` µs, any order):
  `busy` (the fraction of the window the server was serving), `messages` (arrived in the
  window), `mean_wait_ms` (from arrival to the start of service) and `max_queue` (the most
  messages waiting or in service at once).

      iex> TartarusWarehouse.Service.stats([{0, 0, 10_000}, {5_000, 10_000, 20_000}], 0, 40_000)
      %{busy: 0.5, messages: 2, mean_wait_ms: 2.5, max_queue: 2}
  """
  @spec stats([{integer(), integer(), integer()}], integer(), integer()) :: map()
  def stats(log, from_us, to_us) when to_us > from_us do
    busy =
      log
      |> Enum.map(fn {_, s, d} -> max(0, min(d, to_us) - max(s, from_us)) end)
      |> Enum.sum()

    inside = Enum.filter(log, fn {a, _, _} -> a >= from_us and a <= to_us end)

    wait =
      case inside do
        [] -> 0.0
        xs -> Enum.sum(Enum.map(xs, fn {a, s, _} -> s - a end)) / length(xs) / 1000
      end

    %{
      busy: Float.round(busy / (to_us - from_us), 4),
      messages: length(inside),
      mean_wait_ms: Float.round(wait, 3),
      max_queue: max_queue(log, from_us, to_us)
    }
  end

  defp max_queue(log, from_us, to_us) do
    log
    |> Enum.flat_map(fn {a, _, d} -> [{a, 1}, {d, -1}] end)
    |> Enum.sort()
    |> Enum.reduce({0, 0}, fn {t, delta}, {n, best} ->
      n = n + delta
      {n, if(t >= from_us and t <= to_us, do: max(best, n), else: best)}
    end)
    |> elem(1)
  end

  @doc """
  The log as a time series from `t0_us`, in bins of `bin_ms`, up to `t1_us`: `{t_ms,
  busy, queue}` per bin (the bin's start, ms from `t0_us`; the fraction of the bin the
  server was serving; the messages waiting or in service at the bin's end).

      iex> TartarusWarehouse.Service.timeline([{0, 0, 5_000}, {1_000, 5_000, 10_000}], 0, 10_000, 5)
      [{0, 1.0, 1}, {5, 1.0, 0}]
  """
  @spec timeline([{integer(), integer(), integer()}], integer(), integer(), pos_integer()) ::
          [{number(), float(), non_neg_integer()}]
  def timeline(log, t0_us, t1_us, bin_ms) do
    bin = bin_ms * 1000
    bins = max(1, div(t1_us - t0_us + bin - 1, bin))

    for i <- 0..(bins - 1) do
      from = t0_us + i * bin
      to = from + bin

      busy =
        log
        |> Enum.map(fn {_, s, d} -> max(0, min(d, to) - max(s, from)) end)
        |> Enum.sum()

      queue = Enum.count(log, fn {a, _, d} -> a < to and d > to end)
      {i * bin_ms, Float.round(busy / bin, 4), queue}
    end
  end
end
