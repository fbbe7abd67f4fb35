defmodule TartarusTools.Progress do
  @moduledoc """
  A one-line progress display for long runs, redrawn in place with `\\r` on standard error:

      lats  45.0%  450/1000  123.4/s  elapsed 0:03  ETA 0:04

  It is plain data threaded through the run loop (no process):

      progress = TartarusTools.Progress.new(1000, label: "lats", quiet: opts[:quiet])
      progress = Enum.reduce(1..1000, progress, fn _, p -> TartarusTools.Progress.advance(p) end)
      TartarusTools.Progress.finish(progress)

  It prints nothing when `quiet: true` or when standard error is not a terminal (CI logs,
  redirected output), unless `enabled: true` forces it. Redraws are throttled to one per
  `:interval_ms` (default 200). `finish/1` draws the final line and a newline.
  `render/2` is the pure formatting function, for tests.
  """

  defstruct total: 0,
            done: 0,
            label: "",
            enabled: false,
            device: :standard_error,
            started_ms: 0,
            last_ms: nil,
            interval_ms: 200

  @type t :: %__MODULE__{
          total: non_neg_integer,
          done: non_neg_integer,
          label: String.t(),
          enabled: boolean,
          device: IO.device(),
          started_ms: integer,
          last_ms: integer | nil,
          interval_ms: non_neg_integer
        }

  @doc """
  A progress line for `total` units of work. Options: `:label`, `:quiet`, `:enabled`
  (overrides the terminal check), `:device` (default `:standard_error`), `:interval_ms`.
  """
  @spec new(non_neg_integer, keyword) :: t
  def new(total, opts \\ []) when is_integer(total) and total >= 0 do
    device = Keyword.get(opts, :device, :standard_error)

    enabled =
      case Keyword.fetch(opts, :enabled) do
        {:ok, flag} -> flag == true
        :error -> Keyword.get(opts, :quiet) != true and tty?(device)
      end

    %__MODULE__{
      total: total,
      label: to_string(Keyword.get(opts, :label, "")),
      enabled: enabled,
      device: device,
      started_ms: now_ms(),
      interval_ms: Keyword.get(opts, :interval_ms, 200)
    }
  end

  @doc "Records `n` more units done (default 1), redrawing the line if due."
  @spec advance(t, non_neg_integer) :: t
  def advance(%__MODULE__{} = p, n \\ 1) do
    p = %{p | done: p.done + n}

    if p.enabled do
      now = now_ms()

      if p.last_ms == nil or now - p.last_ms >= p.interval_ms or p.done >= p.total do
        IO.write(p.device, ["\r", render(p, now), "\e[K"])
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

  def draw(%__MODULE__{} = p), do: IO.write(p.device, ["\r", render(p, now_ms()), "\e[K"])

  @doc "Draws the final line followed by a newline (if enabled). Returns `:ok`."
  @spec finish(t) :: :ok
  def finish(%__MODULE__{enabled: false}), do: :ok

  def finish(%__MODULE__{} = p) do
    IO.write(p.device, ["\r", render(p, now_ms()), "\e[K\n"])
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
