defmodule TartarusArena.PNG do
  @moduledoc """
  A minimal PNG encoder (8-bit RGB, no interlace) on `:zlib` and `:erlang.crc32/1`.

      iex> png = TartarusArena.PNG.encode(2, 1, [<<255, 0, 0, 0, 0, 255>>])
      iex> <<137, "PNG", 13, 10, 26, 10, _::binary>> = png
      iex> TartarusArena.PNG.size(png)
      {2, 1}
  """

  @doc """
  Encodes an image `width` x `height` given as `height` rows, top first, each a binary of
  `3 * width` bytes (R, G, B). Raises `ArgumentError` if a row has the wrong size.
  """
  @spec encode(pos_integer(), pos_integer(), [binary()]) :: binary()
  def encode(width, height, rows) when length(rows) == height do
    raw =
      for row <- rows, into: <<>> do
        if byte_size(row) != 3 * width do
          raise ArgumentError,
                "PNG row: expected #{3 * width} bytes, got: #{byte_size(row)}"
        end

        <<0, row::binary>>
      end

    <<137, 80, 78, 71, 13, 10, 26, 10>> <>
      chunk("IHDR", <<width::32, height::32, 8, 2, 0, 0, 0>>) <>
      chunk("IDAT", :zlib.compress(raw)) <> chunk("IEND", <<>>)
  end

  defp chunk(type, data),
    do: <<byte_size(data)::32, type::binary, data::binary, :erlang.crc32(type <> data)::32>>

  @doc "The `{width, height}` of a PNG binary (read from its header)."
  @spec size(binary()) :: {pos_integer(), pos_integer()}
  def size(<<137, 80, 78, 71, 13, 10, 26, 10, _len::32, "IHDR", w::32, h::32, _::binary>>),
    do: {w, h}

  @doc """
  Decodes a PNG written by `encode/3` back to its rows (for tests): `{width, height, rows}`.
  Checks every chunk's CRC.
  """
  @spec decode(binary()) :: {pos_integer(), pos_integer(), [binary()]}
  def decode(<<137, 80, 78, 71, 13, 10, 26, 10, rest::binary>>) do
    chunks = chunks(rest, [])
    <<w::32, h::32, 8, 2, 0, 0, 0>> = Map.fetch!(chunks, "IHDR")
    raw = :zlib.uncompress(Map.fetch!(chunks, "IDAT"))
    rows = for <<0, row::binary-size(3 * w) <- raw>>, do: row
    {w, h, rows}
  end

  defp chunks(<<>>, acc), do: Map.new(acc)

  defp chunks(
         <<len::32, type::binary-size(4), data::binary-size(len), crc::32, rest::binary>>,
         acc
       ) do
    if :erlang.crc32(type <> data) != crc, do: raise(ArgumentError, "PNG chunk #{type}: bad CRC")
    chunks(rest, [{type, data} | acc])
  end
end
