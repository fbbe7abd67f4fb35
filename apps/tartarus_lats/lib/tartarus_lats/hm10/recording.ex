defmodule TartarusLats.HM10.Recording do
  @moduledoc """
  Recorded serial output of the nodes' HM-10 receivers: what `mix tartarus.lats --record
  FILE` writes and `--replay FILE` feeds back to the nodes.

  A recording is a text file (gzip-compressed when its name ends in `.gz`), one line per
  node and second:

      # tartarus-lats hm10 recording v1
      121 p1 OK+DISISOK+DISC:4C000215:...:-061OK+DISCE
      121 p2 OK+DISISOK+DISCE

  `SECOND NODE SERIAL`: the world second (an integer), the node's name as in the building,
  and the bytes its HM-10 printed for that second's scan, exactly, with `\\r`, `\\n` and
  `\\\\` escaped and any other byte outside printable ASCII written as `\\xHH`. Lines
  starting with `#` and blank lines are comments. A node with no line for a second heard
  nothing that second. Each node's serial text is fed to one `TartarusLats.HM10` parser in
  order of seconds, so a scan may be split across lines as a real capture cuts it.

  A real capture can be written in this format by a bridge that stamps each second's bytes
  from a node's UART, reading the tty as `Tartarus.Plugin.Serial` does (no such bridge is
  written yet; live HM-10 output goes to `TartarusLats.HM10.Receiver`).
  """

  @header "# tartarus-lats hm10 recording v1\n"

  @typedoc "Serial text per second and node name."
  @type t :: %{non_neg_integer() => %{String.t() => binary()}}

  @doc "The first line of a recording."
  @spec header() :: String.t()
  def header, do: @header

  @doc """
  One line of a recording.

      iex> TartarusLats.HM10.Recording.line(7, :p3, "OK+DISIS\\r\\nOK+DISCE")
      "7 p3 OK+DISIS\\\\r\\\\nOK+DISCE\\n"
  """
  @spec line(non_neg_integer(), atom() | String.t(), binary()) :: String.t()
  def line(second, node, serial) when is_integer(second) and second >= 0 and is_binary(serial),
    do: "#{second} #{node} #{escape(serial)}\n"

  @doc """
  Reads a recording (`.gz` is decompressed). Returns `{:ok, recording}` or `{:error,
  message}` naming the file and line that is wrong, e.g. `"rec.hm10:4: expected SECOND
  NODE SERIAL, got: \"bad\""`.
  """
  @spec read(Path.t()) :: {:ok, t()} | {:error, String.t()}
  def read(path) do
    with {:ok, bin} <- File.read(path),
         {:ok, text} <- maybe_gunzip(path, bin) do
      text
      |> String.split("\n")
      |> Enum.with_index(1)
      |> Enum.reduce_while({:ok, %{}}, fn {line, n}, {:ok, acc} ->
        case parse_line(line) do
          :skip -> {:cont, {:ok, acc}}
          {:ok, t, node, serial} -> {:cont, {:ok, add(acc, t, node, serial)}}
          {:error, why} -> {:halt, {:error, "#{path}:#{n}: #{why}"}}
        end
      end)
    else
      {:error, reason} when is_atom(reason) ->
        {:error, "#{path}: #{:file.format_error(reason)}"}

      error ->
        error
    end
  end

  defp maybe_gunzip(path, bin) do
    if String.ends_with?(path, ".gz") do
      try do
        {:ok, :zlib.gunzip(bin)}
      rescue
        _ -> {:error, "#{path}: not a gzip file"}
      end
    else
      {:ok, bin}
    end
  end

  defp add(acc, t, node, serial) do
    Map.update(acc, t, %{node => serial}, fn nodes ->
      Map.update(nodes, node, serial, &(&1 <> serial))
    end)
  end

  defp parse_line(""), do: :skip
  defp parse_line("#" <> _), do: :skip

  defp parse_line(line) do
    with [second, node | rest] <- String.split(line, " ", parts: 3),
         {t, ""} when t >= 0 <- Integer.parse(second),
         true <- node != "",
         {:ok, serial} <- unescape(Enum.join(rest)) do
      {:ok, t, node, serial}
    else
      {:error, why} -> {:error, why}
      _ -> {:error, "expected SECOND NODE SERIAL, got: #{inspect(line)}"}
    end
  end

  @doc false
  def escape(serial) do
    for <<c <- serial>>, into: "" do
      case c do
        ?\r -> "\\r"
        ?\n -> "\\n"
        ?\\ -> "\\\\"
        c when c in 0x20..0x7E -> <<c>>
        c -> "\\x" <> Base.encode16(<<c>>)
      end
    end
  end

  defp unescape(text), do: unescape(text, [])

  defp unescape(<<>>, acc), do: {:ok, acc |> Enum.reverse() |> IO.iodata_to_binary()}
  defp unescape(<<"\\r", rest::binary>>, acc), do: unescape(rest, ["\r" | acc])
  defp unescape(<<"\\n", rest::binary>>, acc), do: unescape(rest, ["\n" | acc])
  defp unescape(<<"\\\\", rest::binary>>, acc), do: unescape(rest, ["\\" | acc])

  defp unescape(<<"\\x", hex::binary-2, rest::binary>> = all, acc) do
    case Base.decode16(hex, case: :mixed) do
      {:ok, byte} -> unescape(rest, [byte | acc])
      :error -> {:error, "bad escape in serial text at: #{inspect(binary_part(all, 0, 4))}"}
    end
  end

  defp unescape(<<"\\", _::binary>> = all, _acc),
    do:
      {:error,
       "bad escape in serial text at: #{inspect(binary_part(all, 0, min(4, byte_size(all))))}"}

  defp unescape(<<c, rest::binary>>, acc), do: unescape(rest, [<<c>> | acc])
end
