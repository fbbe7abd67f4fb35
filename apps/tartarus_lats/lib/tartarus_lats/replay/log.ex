defmodule TartarusLats.Replay.Log do
  @moduledoc """
  A log of RSSI readings from many receivers: the input of a real-data replay
  (`TartarusLats.Replay`).

  ## The format

  Text, one reading a line, comma-separated:

      time, receiver, beacon, rssi[, x, y[, anything else]]

    * `time` - seconds (a number; Unix seconds with a fraction in the tetam recordings);
    * `receiver` - the receiver's id as in the devices file (`TartarusLats.Replay.Devices`);
    * `beacon` - the beacon's id (a MAC such as `e78f135624ce`, or 32 hex digits);
    * `rssi` - dBm, a number from -127 to 0;
    * `x, y` - optional, the beacon's true position in metres at that reading (the ground
      truth). Columns after them are ignored.

  Blank lines, lines starting with `#` and a header line whose first field is `time` are
  skipped. The tetam `.mbd` files are this format as they are (`x, y, z` and the
  orientation matrix after the RSSI: `z` and the rest are ignored), and so are its
  fingerprint files (four columns). Lines are read in any time order and sorted.

  A malformed line (too few fields, a time or RSSI that is not a number, an RSSI out of
  range, an empty receiver or beacon, an `x` without `y` or a position that is not a number)
  is skipped and counted with its line number and why: `parse/1` never raises on content.
  Every line ends with a newline: a text whose last line has none (a file cut short, say
  in the middle of an RSSI: `-7` for `-74`) does not read that line; it is counted as a bad
  line and named in `unterminated`.

      iex> log = TartarusLats.Replay.Log.parse("1.5,r1,aa,-70,1.0,2.0\\nbad line\\n2.0,r2,aa,-71\\n")
      iex> Enum.map(log.readings, &{&1.time, &1.receiver, &1.rssi, &1.pos})
      [{1.5, "r1", -70, {1.0, 2.0}}, {2.0, "r2", -71, nil}]
      iex> log.bad
      [{2, "expected time, receiver, beacon, rssi[, x, y], got 1 field"}]
      iex> log = TartarusLats.Replay.Log.parse("1.5,r1,aa,-70\\n2.0,r2,aa,-7")
      iex> {length(log.readings), log.bad, log.unterminated}
      {1, [{2, "last line has no newline (cut short?): not read"}], 2}
  """

  @typedoc "One reading."
  @type reading :: %{
          time: float(),
          receiver: String.t(),
          beacon: String.t(),
          rssi: number(),
          pos: {float(), float()} | nil,
          line: pos_integer()
        }

  @typedoc """
  A parsed log: readings sorted by time (then line), the malformed lines, the lines that
  were not blank, comments or a header, and the number of a last line left unread because
  the text did not end with a newline (nil: it did).
  """
  @type t :: %{
          readings: [reading()],
          bad: [{pos_integer(), String.t()}],
          lines: non_neg_integer(),
          unterminated: pos_integer() | nil
        }

  @doc """
  Parses a log's text (or a list of lines). Never raises on content; see the moduledoc.
  """
  @spec parse(binary() | [binary()]) :: t()
  def parse(text) when is_binary(text) do
    lines = String.split(text, ["\r\n", "\n"])
    # The text of a file that does not end with a newline: its last line may have been cut
    # short (a copy or a write interrupted in the middle of a number), so it is not read.
    {lines, cut} =
      case List.last(lines) do
        "" -> {lines, nil}
        last -> {List.replace_at(lines, -1, ""), {length(lines), last}}
      end

    log = parse(lines)

    case cut do
      nil ->
        log

      {no, last} ->
        if parse_line(last, no) == :skip,
          do: log,
          else: %{
            log
            | bad: log.bad ++ [{no, "last line has no newline (cut short?): not read"}],
              lines: log.lines + 1,
              unterminated: no
          }
    end
  end

  def parse(lines) when is_list(lines) do
    {readings, bad, n} =
      lines
      |> Enum.with_index(1)
      |> Enum.reduce({[], [], 0}, fn {line, no}, {ok, bad, n} ->
        case parse_line(line, no) do
          :skip -> {ok, bad, n}
          {:ok, r} -> {[r | ok], bad, n + 1}
          {:error, why} -> {ok, [{no, why} | bad], n + 1}
        end
      end)

    %{
      readings: Enum.sort_by(readings, &{&1.time, &1.line}),
      bad: Enum.reverse(bad),
      lines: n,
      unterminated: nil
    }
  end

  @doc "Reads and parses a log file (`parse/1`). Raises `File.Error` if it cannot be read."
  @spec read!(Path.t()) :: t()
  def read!(path), do: path |> File.read!() |> parse()

  @doc """
  Parses one line: `{:ok, reading}`, `:skip` (blank, comment, header) or `{:error, why}`;
  it never raises on content (a number longer than 32 characters or larger than 1.0e12 is
  an error of its line).

      iex> TartarusLats.Replay.Log.parse_line("10,r1,aa,-300", 4)
      {:error, "rssi out of range (-127..0): -300"}
      iex> TartarusLats.Replay.Log.parse_line(String.duplicate("9", 400) <> ",r1,aa,-70", 5)
      {:error, "time is longer than 32 characters"}
      iex> TartarusLats.Replay.Log.parse_line("1.0e300,r1,aa,-70", 6)
      {:error, "time is out of range (at most 1.0e12 in size): 1.0e300"}
      iex> TartarusLats.Replay.Log.parse_line("# a comment", 1)
      :skip
  """
  @spec parse_line(binary(), pos_integer()) :: {:ok, reading()} | :skip | {:error, String.t()}
  def parse_line(line, no) when is_binary(line) do
    trimmed = String.trim(line)

    cond do
      trimmed == "" or String.starts_with?(trimmed, "#") ->
        :skip

      true ->
        fields = trimmed |> String.split(",") |> Enum.map(&String.trim/1)

        case fields do
          ["time" | _] -> :skip
          [t, rx, bc, rssi | rest] -> reading(t, rx, bc, rssi, rest, no)
          _ -> {:error, "expected time, receiver, beacon, rssi[, x, y], got #{count(fields)}"}
        end
    end
  end

  defp count([_]), do: "1 field"
  defp count(fields), do: "#{length(fields)} fields"

  defp reading(t, rx, bc, rssi, rest, no) do
    with {:ok, time} <- number(t, "time"),
         {:ok, rssi} <- rssi(rssi),
         :ok <- in_range(rssi),
         :ok <- present(rx, "receiver"),
         :ok <- present(bc, "beacon"),
         {:ok, pos} <- position(rest) do
      {:ok,
       %{time: time, receiver: rx, beacon: String.downcase(bc), rssi: rssi, pos: pos, line: no}}
    end
  end

  defp in_range(rssi) when rssi >= -127 and rssi <= 0, do: :ok
  defp in_range(rssi), do: {:error, "rssi out of range (-127..0): #{fmt(rssi)}"}

  defp fmt(x) when is_float(x) and x == trunc(x), do: Integer.to_string(trunc(x))
  defp fmt(x), do: to_string(x)

  defp present("", what), do: {:error, "empty #{what}"}
  defp present(_, _), do: :ok

  defp position([]), do: {:ok, nil}
  defp position([_x]), do: {:error, "x without y"}

  defp position([x, y | _]) do
    with {:ok, x} <- number(x, "x"), {:ok, y} <- number(y, "y"), do: {:ok, {x, y}}
  end

  # A number of at most @max_digits characters and at most @max_abs in size (a time in
  # seconds, a coordinate in metres, an RSSI): anything longer or larger is a bad line, not
  # a raise (`Float.parse/1` raises on a value beyond a double's range).
  @max_digits 32
  @max_abs 1.0e12

  # An RSSI is kept as the receiver wrote it: an integer when it is one.
  defp rssi(s) do
    case byte_size(s) <= @max_digits and Integer.parse(s) do
      {i, ""} -> {:ok, i}
      _ -> number(s, "rssi")
    end
  end

  defp number(s, what) when byte_size(s) > @max_digits,
    do: {:error, "#{what} is longer than #{@max_digits} characters"}

  defp number(s, what) do
    case Float.parse(s) do
      {x, ""} when abs(x) <= @max_abs -> {:ok, x}
      {_x, ""} -> {:error, "#{what} is out of range (at most 1.0e12 in size): #{s}"}
      _ -> {:error, "#{what} is not a number: #{inspect(s)}"}
    end
  rescue
    ArgumentError -> {:error, "#{what} is out of range: #{String.slice(s, 0, 16)}..."}
  end

  @doc """
  The readings grouped into whole seconds from the first reading's second, as a replay
  feeds them (second 1 is the first): `%{second => %{receiver => %{beacon => rssi}}}`,
  where `rssi` is the mean of the receiver's readings of that beacon in that second,
  rounded to a whole dBm (a receiver reports about twice a second; the trackers take one
  sample a second). Also returns the start time (`t0`, the first reading's time rounded
  down).

      iex> log = TartarusLats.Replay.Log.parse("100.2,r1,aa,-70\\n100.7,r1,aa,-74\\n101.1,r2,aa,-80\\n")
      iex> TartarusLats.Replay.Log.per_second(log)
      {100.0, %{1 => %{"r1" => %{"aa" => -72}}, 2 => %{"r2" => %{"aa" => -80}}}}
  """
  @spec per_second(t()) ::
          {float(), %{pos_integer() => %{String.t() => %{String.t() => integer()}}}}
  def per_second(%{readings: []}), do: {0.0, %{}}

  def per_second(%{readings: [first | _] = readings}) do
    t0 = Float.floor(first.time)

    grouped =
      readings
      |> Enum.group_by(&{second(&1.time, t0), &1.receiver, &1.beacon}, & &1.rssi)
      |> Enum.reduce(%{}, fn {{s, rx, bc}, values}, acc ->
        mean = round(Enum.sum(values) / length(values))
        Map.update(acc, s, %{rx => %{bc => mean}}, &put_in(&1, [Access.key(rx, %{}), bc], mean))
      end)

    {t0, grouped}
  end

  @doc "The second (1, 2, ...) of time `time` in a replay that starts at `t0`."
  @spec second(number(), number()) :: pos_integer()
  def second(time, t0), do: trunc(Float.floor((time - t0) * 1.0)) + 1

  @doc """
  The true position of `beacon` in every second that has one: the position of the
  second's last reading that carries one. `%{second => {x, y}}`.
  """
  @spec positions(t(), float(), String.t()) :: %{pos_integer() => {float(), float()}}
  def positions(%{readings: readings}, t0, beacon) do
    for %{beacon: ^beacon, pos: {_, _} = pos} = r <- readings,
        into: %{},
        do: {second(r.time, t0), pos}
  end

  @doc "The beacons of a log, sorted."
  @spec beacons(t()) :: [String.t()]
  def beacons(%{readings: readings}),
    do: readings |> Enum.map(& &1.beacon) |> Enum.uniq() |> Enum.sort()
end
