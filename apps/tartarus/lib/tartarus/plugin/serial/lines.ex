defmodule Tartarus.Plugin.Serial.Lines do
  @moduledoc """
  A `Tartarus.Plugin.Serial.Decoder` for text lines: each line (without its separator and
  a trailing `\\r`) is an event `{:line, text}`; a line longer than `:max_line` bytes is
  dropped as `{:overflow, bytes}`.

      iex> alias Tartarus.Plugin.Serial.Lines
      iex> {:ok, d} = Lines.init([])
      iex> {events, d} = Lines.feed("temp=2", d)
      iex> events
      []
      iex> {events, d} = Lines.feed("1.5\\r\\nhum=40\\n", d)
      iex> events
      [{:line, "temp=21.5"}, {:line, "hum=40"}]
      iex> Lines.read(:last, d) |> elem(1)
      "hum=40"

  Options: `:separator` (default `"\\n"`), `:max_line` (default 1024). Reads: `:last` (the
  last line, or `nil`), `:lines` (the lines received since the previous `:lines` read, at
  most the last 100, oldest first).
  """
  @behaviour Tartarus.Plugin.Serial.Decoder

  @keep 100

  @impl true
  def init(opts) do
    sep = Keyword.get(opts, :separator, "\n")
    max = Keyword.get(opts, :max_line, 1024)

    if is_binary(sep) and sep != "" and is_integer(max) and max > 0 do
      {:ok, %{sep: sep, max: max, buf: <<>>, last: nil, unread: []}}
    else
      {:error,
       "invalid options given to Tartarus.Plugin.Serial.Lines: expected a non-empty :separator and a positive :max_line, got: #{inspect(opts)}"}
    end
  end

  @impl true
  def feed(bytes, d) do
    [rest | lines] = (d.buf <> bytes) |> :binary.split(d.sep, [:global]) |> Enum.reverse()
    lines = Enum.reverse(lines)

    events =
      Enum.map(lines, fn line ->
        line = String.trim_trailing(line, "\r")
        if byte_size(line) > d.max, do: {:overflow, line}, else: {:line, line}
      end)

    {events, rest} =
      if byte_size(rest) > d.max, do: {events ++ [{:overflow, rest}], <<>>}, else: {events, rest}

    taken = for {:line, l} <- events, do: l
    unread = Enum.take(d.unread ++ taken, -@keep)
    last = List.last(taken) || d.last
    {events, %{d | buf: rest, last: last, unread: unread}}
  end

  @impl true
  def reset(%{buf: <<>>} = d), do: {[], d}
  def reset(d), do: {[{:dropped, d.buf}], %{d | buf: <<>>}}

  @impl true
  def read(:last, d), do: {:ok, d.last, d}
  def read(:lines, d), do: {:ok, d.unread, %{d | unread: []}}
  def read(arg, d), do: {:error, {:bad_argument, arg}, d}

  @impl true
  def describe(_d), do: %{reads: [:last, :lines], events: [:line, :overflow, :dropped]}
end
