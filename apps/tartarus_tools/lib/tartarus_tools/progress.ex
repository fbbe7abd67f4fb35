defmodule TartarusTools.Progress do
  @moduledoc """
  A one-line progress display for long runs, redrawn in place with `\\r` on standard error:

      lats  45.0%  450/1000  123.4/s  elapsed 0:03  ETA 0:04

  It is plain data threaded through the run loop (no process):

      progress = TartarusTools.Progress.new(1000, label: "lats", quiet: opts[:quiet])
      progress = Enum.reduce(1..1000, progress, fn _, p -> TartarusTools.Progress.advance(p) end)
      TartarusTools.Progress.finish(progress)

  It prints nothing when `quiet: true` or when standard error is not a terminal (CI logs,
  redirected output), unless `enabled: true` forces it, or the run was asked for progress
  (`force/1`: a mix task's `--progress`, `TartarusTools.CLI`). Redraws are throttled to one
  per `:interval_ms` (default 200). On a device that is not a terminal (a log file, a pipe)
  a forced line is written as a plain line of its own, at most one every 10 s, so the log
  of a long run holds a readable line every 10 s rather than thousands of redraws.
  `finish/1` draws the final line and a newline.
  `render/2` is the pure formatting function, for tests.

  Nothing is printed while the VM runs in virtual time (`Tartarus.Clock.virtual?/0`): a
  process waiting for its output to be written looks idle to the virtual clock, which would
  move the time past it.
  """

  @plain_interval_ms 10_000

  defstruct total: 0,
            done: 0,
            label: "",
            enabled: false,
            device: :standard_error,
            started_ms: 0,
            last_ms: nil,
            interval_ms: 200,
            plain: false

  @type t :: %__MODULE__{
          total: non_neg_integer,
          done: non_neg_integer,
          label: String.t(),
          enabled: boolean,
          device: IO.device(),
          started_ms: integer,
          last_ms: integer | nil,
          interval_ms: non_neg_integer,
          plain: boolean
        }

  @doc """
  A progress line for `total` units of work. Options: `:label`, `:quiet`, `:enabled`
  (overrides the terminal check and `force/1`), `:device` (default `:standard_error`;
  `false`: no line whatever `force/1` asked, for a run inside a sweep, which has its own
  line per run), `:interval_ms`.
  """
  @spec new(non_neg_integer, keyword) :: t
  def new(total, opts \\ []) when is_integer(total) and total >= 0 do
    device = Keyword.get(opts, :device, :standard_error)
    tty? = device != false and tty?(device)

    enabled =
      case Keyword.fetch(opts, :enabled) do
        {:ok, flag} -> flag == true
        :error when device == false -> false
        :error -> forced?() or (Keyword.get(opts, :quiet) != true and tty?)
      end

    interval_ms = Keyword.get(opts, :interval_ms, 200)
    plain = enabled and not tty? and Keyword.get(opts, :enabled) != true

    %__MODULE__{
      total: total,
      label: to_string(Keyword.get(opts, :label, "")),
      enabled: enabled,
      device: device,
      started_ms: now_ms(),
      interval_ms: if(plain, do: max(interval_ms, @plain_interval_ms), else: interval_ms),
      plain: plain
    }
  end

  @doc """
  Asks for progress lines in this VM (`true`) or leaves it to `new/2`'s rules again
  (`false`): with `true`, every `new/2` without `:enabled` is enabled even when it is
  `quiet:` or its device is not a terminal, and so are `TartarusEmu.Sweep`'s lines per
  run. A mix task's `--progress` calls it (`TartarusTools.CLI`). Returns `:ok`.
  """
  @spec force(boolean) :: :ok
  def force(true), do: :persistent_term.put({__MODULE__, :forced}, true)

  def force(false) do
    _ = :persistent_term.erase({__MODULE__, :forced})
    :ok
  end

  @doc "Whether progress lines were asked for in this VM (`force/1`)."
  @spec forced?() :: boolean
  def forced?, do: :persistent_term.get({__MODULE__, :forced}, false)

  @doc "Records `n` more units done (default 1), redrawing the line if due."
  @spec advance(t, non_neg_integer) :: t
  def advance(%__MODULE__{} = p, n \\ 1) do
    p = %{p | done: p.done + n}

    if p.enabled do
      now = now_ms()

      if p.last_ms == nil or now - p.last_ms >= p.interval_ms or p.done >= p.total do
        write(p, now, false)
        %{p | last_ms: now}
      else
        p
      end
    else
      p
    end
  end

  @doc """
  Redraws the line of `p` as it is now (if enabled), unthrottled: for a caller that keeps
  its own count and is called back at its own pace. Returns `:ok`.
  """
  @spec draw(t) :: :ok
  def draw(%__MODULE__{enabled: false}), do: :ok

  def draw(%__MODULE__{} = p), do: write(p, now_ms(), false)

  @doc "Draws the final line followed by a newline (if enabled). Returns `:ok`."
  @spec finish(t) :: :ok
  def finish(%__MODULE__{enabled: false}), do: :ok

  def finish(%__MODULE__{} = p), do: write(p, now_ms(), true)

  # A terminal's line is redrawn in place; a plain device gets a line of its own each time.
  defp write(p, now, last?) do
    cond do
      Tartarus.Clock.virtual?() -> :ok
      p.plain -> IO.write(p.device, [render(p, now), "\n"])
      true -> IO.write(p.device, ["\r", render(p, now), "\e[K", if(last?, do: "\n", else: [])])
    end
  end

  @doc """
  The progress line at monotonic time `now_ms` (milliseconds, same clock as `new/2`).

  ## Examples

      iex> p = %TartarusTools.Progress{total: 200, done: 50, label: "run", started_ms: 0}
      iex> TartarusTools.Progress.render(p, 10_000)
      "run  25.0%  50/200  5.0/s  elapsed 0:10  ETA 0:30"
      iex> TartarusTools.Progress.render(%{p | done: 0}, 0)
      "run  0.0%  0/200  0.0/s  elapsed 0:00  ETA --:--"
  """
  @spec render(t, integer) :: String.t()
  def render(%__MODULE__{} = p, now_ms) do
    elapsed = max(now_ms - p.started_ms, 0) / 1000
    rate = if elapsed > 0, do: p.done / elapsed, else: 0.0
    percent = if p.total > 0, do: 100 * p.done / p.total, else: 100.0

    eta =
      cond do
        p.done >= p.total -> "0:00"
        rate > 0 -> clock(round((p.total - p.done) / rate))
        true -> "--:--"
      end

    [
      if(p.label == "", do: [], else: [p.label, "  "]),
      :erlang.float_to_binary(percent * 1.0, decimals: 1),
      "%  ",
      "#{p.done}/#{p.total}  ",
      :erlang.float_to_binary(rate * 1.0, decimals: 1),
      "/s  elapsed ",
      clock(trunc(elapsed)),
      "  ETA ",
      eta
    ]
    |> IO.iodata_to_binary()
  end

  defp clock(seconds) when seconds >= 3600,
    do: "#{div(seconds, 3600)}:#{pad(div(rem(seconds, 3600), 60))}:#{pad(rem(seconds, 60))}"

  defp clock(seconds), do: "#{div(seconds, 60)}:#{pad(rem(seconds, 60))}"

  defp pad(n), do: n |> Integer.to_string() |> String.pad_leading(2, "0")

  defp tty?(device) do
    match?({:ok, _}, :io.columns(device))
  rescue
    _ -> false
  end

  defp now_ms, do: Tartarus.Clock.machine_time(:millisecond)
end
