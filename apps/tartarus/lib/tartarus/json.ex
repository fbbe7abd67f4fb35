defmodule Tartarus.JSON do
  @moduledoc """
  A small, dependency-free JSON encoder and decoder (RFC 8259).

  hex.pm is out of reach on our build machines, so the umbrella carries its own JSON, in the
  platform: the dashboard's API speaks it, and the lab writes `summary.json` files,
  benchmark output and anything else machine-readable with it. It is not tuned for
  megabytes per second, but it is strict and deterministic.

  ## Example

      iex> json = Tartarus.JSON.encode!(%{name: "h1", hops: 3, tags: [:fast, nil]})
      ~s({"hops":3,"name":"h1","tags":["fast",null]})
      iex> Tartarus.JSON.decode(json)
      {:ok, %{"hops" => 3, "name" => "h1", "tags" => ["fast", nil]}}

  ## Encoding

  | Elixir                               | JSON                                   |
  |--------------------------------------|----------------------------------------|
  | map with atom or string keys         | object; keys **sorted** (deterministic) |
  | list                                 | array                                  |
  | binary (valid UTF-8)                 | string, escaped                        |
  | integer                              | number                                 |
  | float                                | number, shortest round-trip form       |
  | `true`, `false`, `nil`               | `true`, `false`, `null`                |
  | any other atom                       | string (`:ok` becomes `"ok"`)          |
  | `Date`, `Time`, `NaiveDateTime`, `DateTime` | ISO 8601 string                 |

  Strings are written as UTF-8; `"`, `\\` and every control character below U+0020 are
  escaped (`\\n`, `\\t`, ... or `\\u00XX`). Anything else (tuples, pids, other structs,
  binaries that are not UTF-8, maps with other keys, two keys that become the same string
  such as `:a` and `"a"`) raises `ArgumentError` naming what was expected and what arrived.

  BEAM floats are always finite, so there is no NaN or infinity to meet; the atoms `:nan`,
  `:infinity` and `:neg_infinity`, which code often uses as stand-ins for them, are refused
  with `ArgumentError` instead of silently becoming strings.

  `pretty: true` indents with two spaces and puts one member per line.

  ## Decoding

  `decode/1` returns `{:ok, term}` or `{:error, {:invalid_json, position}}` where `position`
  is the 0-based **byte** offset of the first offending byte (the input size when the input
  ends too early). Objects become maps with **string** keys (never atoms: decoding untrusted
  input must not grow the atom table); when a key repeats, the last value wins. Numbers with
  a fraction or an exponent become floats, others integers (of any size). `\\uXXXX` escapes
  are supported, including surrogate pairs; a lone surrogate is an error. A number too large
  for a float (such as `1e400`) is reported as an error at its position.
  `decode!/1` raises `Tartarus.JSON.DecodeError` instead.
  """

  defmodule DecodeError do
    @moduledoc """
    Raised by `Tartarus.JSON.decode!/1` for invalid JSON.

    `position` is the 0-based byte offset of the problem.
    """
    defexception [:position, :data]

    @impl true
    def message(%{position: position, data: data}) do
      found =
        case data do
          <<_::binary-size(position), char::utf8, _::binary>> ->
            "found #{inspect(<<char::utf8>>)}"

          <<_::binary-size(position), byte, _::binary>> ->
            "found byte #{byte}"

          _ ->
            "found end of input"
        end

      "invalid JSON at byte #{position}: #{found}"
    end
  end

  @typedoc "Terms `encode!/2` accepts."
  @type encodable ::
          nil
          | boolean
          | atom
          | number
          | String.t()
          | [encodable]
          | %{optional(atom | String.t()) => encodable}

  @typedoc "Terms `decode/1` returns."
  @type decoded ::
          nil | boolean | number | String.t() | [decoded] | %{optional(String.t()) => decoded}

  @typedoc "Options of `encode!/2`: `pretty: true` for indented output (default `false`)."
  @type encode_opts :: [pretty: boolean]

  @doc """
  Encodes `term` as a JSON binary; raises `ArgumentError` if it cannot.

  ## Examples

      iex> Tartarus.JSON.encode!(%{"b" => 1, :a => [1.5, true, nil]})
      ~s({"a":[1.5,true,null],"b":1})

      iex> Tartarus.JSON.encode!("tab\\there \\"quoted\\" é")
      ~s("tab\\\\there \\\\"quoted\\\\" é")

      iex> Tartarus.JSON.encode!(%{a: [1, 2], b: %{}}, pretty: true)
      ~s({\\n  "a": [\\n    1,\\n    2\\n  ],\\n  "b": {}\\n})

      iex> Tartarus.JSON.encode!({:a, 1})
      ** (ArgumentError) Tartarus.JSON.encode!/2 cannot encode {:a, 1}: expected a map, list, binary, number, boolean, nil or atom
  """
  @spec encode!(encodable, encode_opts) :: String.t()
  def encode!(term, opts \\ []) do
    term |> encode_to_iodata!(opts) |> IO.iodata_to_binary()
  end

  @doc """
  Like `encode!/2` but returns iodata, for writing straight to a file or socket.

  ## Examples

      iex> Tartarus.JSON.encode_to_iodata!([1, "x"]) |> IO.iodata_to_binary()
      ~s([1,"x"])
  """
  @spec encode_to_iodata!(encodable, encode_opts) :: iodata
  def encode_to_iodata!(term, opts \\ []) do
    case Keyword.get(opts, :pretty, false) do
      false -> enc(term, nil)
      true -> enc(term, 0)
      other -> raise ArgumentError, "option :pretty: expected a boolean, got: #{inspect(other)}"
    end
  end

  # `indent` is nil for compact output, else the current nesting depth.
  defp enc(nil, _), do: "null"
  defp enc(true, _), do: "true"
  defp enc(false, _), do: "false"

  defp enc(atom, _) when atom in [:nan, :infinity, :neg_infinity] do
    raise ArgumentError,
          "Tartarus.JSON.encode!/2 cannot encode #{inspect(atom)}: " <>
            "expected a finite number, JSON has no NaN or infinity"
  end

  defp enc(atom, _) when is_atom(atom), do: string(Atom.to_string(atom))
  defp enc(int, _) when is_integer(int), do: Integer.to_string(int)
  defp enc(float, _) when is_float(float), do: Float.to_string(float)
  defp enc(bin, _) when is_binary(bin), do: string(bin)

  defp enc(%module{} = struct, _) when module in [Date, Time, NaiveDateTime, DateTime] do
    string(module.to_iso8601(struct))
  end

  defp enc(%module{} = struct, _) do
    raise ArgumentError,
          "Tartarus.JSON.encode!/2 cannot encode struct #{inspect(struct)}: " <>
            "expected a plain map; convert #{inspect(module)} to a map first"
  end

  defp enc(map, indent) when is_map(map) do
    pairs = :lists.keysort(1, :maps.fold(fn k, v, acc -> [{key(k), v} | acc] end, [], map))

    check_duplicate_keys(pairs, map)

    case pairs do
      [] ->
        "{}"

      _ ->
        members =
          Enum.map(pairs, fn {k, v} -> [string(k), colon(indent), enc(v, deeper(indent))] end)

        wrap("{", members, "}", indent)
    end
  end

  defp enc([], _), do: "[]"

  defp enc(list, indent) when is_list(list) do
    if not proper_list?(list) do
      raise ArgumentError,
            "Tartarus.JSON.encode!/2 cannot encode improper list #{inspect(list)}: " <>
              "expected a proper list"
    end

    wrap("[", Enum.map(list, &enc(&1, deeper(indent))), "]", indent)
  end

  defp enc(other, _) do
    raise ArgumentError,
          "Tartarus.JSON.encode!/2 cannot encode #{inspect(other)}: " <>
            "expected a map, list, binary, number, boolean, nil or atom"
  end

  defp proper_list?([]), do: true
  defp proper_list?([_ | tail]), do: proper_list?(tail)
  defp proper_list?(_), do: false

  defp deeper(nil), do: nil
  defp deeper(n), do: n + 1

  defp colon(nil), do: ":"
  defp colon(_), do: ": "

  defp wrap(open, items, close, nil), do: [open, Enum.intersperse(items, ","), close]

  defp wrap(open, items, close, depth) do
    inner = ["\n" | String.duplicate("  ", depth + 1)]

    [
      open,
      inner,
      Enum.intersperse(items, [?, | inner]),
      "\n",
      String.duplicate("  ", depth),
      close
    ]
  end

  defp key(k) when is_binary(k), do: k
  defp key(k) when is_atom(k) and not is_nil(k) and not is_boolean(k), do: Atom.to_string(k)

  defp key(k) do
    raise ArgumentError,
          "Tartarus.JSON.encode!/2 cannot encode map key #{inspect(k)}: " <>
            "expected an atom or a string"
  end

  # The keys, sorted, side by side: two equal ones (an atom and a string that both encode
  # as "a") are refused. One pass (this runs for every map encoded).
  defp check_duplicate_keys([{a, _}, {a, _} | _], map) do
    raise ArgumentError,
          "Tartarus.JSON.encode!/2 cannot encode map #{inspect(map)}: " <>
            "expected unique keys, got two keys that both encode as #{inspect(a)}"
  end

  defp check_duplicate_keys([_ | rest], map), do: check_duplicate_keys(rest, map)
  defp check_duplicate_keys([], _map), do: :ok

  defp string(bin) do
    if not String.valid?(bin) do
      raise ArgumentError,
            "Tartarus.JSON.encode!/2 cannot encode binary #{inspect(bin)}: " <>
              "expected valid UTF-8"
    end

    [?", escape(bin, bin, 0, 0, []), ?"]
  end

  # Walks the binary, copying runs of plain bytes as sub-binaries and escaping the rest.
  defp escape(<<>>, orig, start, len, acc),
    do: Enum.reverse([binary_part(orig, start, len) | acc])

  defp escape(<<byte, rest::binary>>, orig, start, len, acc)
       when byte < 0x20 or byte == ?" or byte == ?\\ do
    acc = [escape_byte(byte), binary_part(orig, start, len) | acc]
    escape(rest, orig, start + len + 1, 0, acc)
  end

  defp escape(<<_, rest::binary>>, orig, start, len, acc),
    do: escape(rest, orig, start, len + 1, acc)

  defp escape_byte(?"), do: "\\\""
  defp escape_byte(?\\), do: "\\\\"
  defp escape_byte(?\n), do: "\\n"
  defp escape_byte(?\r), do: "\\r"
  defp escape_byte(?\t), do: "\\t"
  defp escape_byte(?\b), do: "\\b"
  defp escape_byte(?\f), do: "\\f"

  defp escape_byte(byte) do
    hex = byte |> Integer.to_string(16) |> String.pad_leading(4, "0")
    ["\\u", hex]
  end

  ## Decoding

  @doc """
  Decodes a JSON binary.

  Returns `{:ok, term}` or `{:error, {:invalid_json, position}}` with the 0-based byte offset
  of the problem. Object keys stay strings.

  ## Examples

      iex> Tartarus.JSON.decode(~s({"a": [1, 2.5, "\\\\u00e9\\\\ud83d\\\\ude00"], "b": null}))
      {:ok, %{"a" => [1, 2.5, "é😀"], "b" => nil}}

      iex> Tartarus.JSON.decode("[1, 2,]")
      {:error, {:invalid_json, 6}}

      iex> Tartarus.JSON.decode("")
      {:error, {:invalid_json, 0}}
  """
  @spec decode(binary) :: {:ok, decoded} | {:error, {:invalid_json, non_neg_integer}}
  def decode(binary) when is_binary(binary) do
    size = byte_size(binary)

    try do
      {value, rest} = value(skip_ws(binary), size)

      case skip_ws(rest) do
        "" -> {:ok, value}
        rest -> throw({:invalid, size - byte_size(rest)})
      end
    catch
      {:invalid, position} -> {:error, {:invalid_json, position}}
    end
  end

  @doc """
  Like `decode/1` but returns the term or raises `Tartarus.JSON.DecodeError`.

  ## Examples

      iex> Tartarus.JSON.decode!("[true, false]")
      [true, false]

      iex> Tartarus.JSON.decode!(~s({"a" 1}))
      ** (Tartarus.JSON.DecodeError) invalid JSON at byte 5: found "1"
  """
  @spec decode!(binary) :: decoded
  def decode!(binary) when is_binary(binary) do
    case decode(binary) do
      {:ok, value} -> value
      {:error, {:invalid_json, position}} -> raise DecodeError, position: position, data: binary
    end
  end

  defp fail(rest, size), do: throw({:invalid, size - byte_size(rest)})

  defp skip_ws(<<c, rest::binary>>) when c in [?\s, ?\t, ?\n, ?\r], do: skip_ws(rest)
  defp skip_ws(rest), do: rest

  defp value(<<?{, rest::binary>>, size), do: object(skip_ws(rest), size, %{})
  defp value(<<?[, rest::binary>>, size), do: array(skip_ws(rest), size, [])
  defp value(<<?", rest::binary>>, size), do: string_body(rest, size, [])
  defp value(<<"true", rest::binary>>, _), do: {true, rest}
  defp value(<<"false", rest::binary>>, _), do: {false, rest}
  defp value(<<"null", rest::binary>>, _), do: {nil, rest}
  defp value(<<c, _::binary>> = data, size) when c == ?- or c in ?0..?9, do: number(data, size)
  defp value(rest, size), do: fail(rest, size)

  defp object(<<?}, rest::binary>>, _size, acc) when acc == %{}, do: {acc, rest}

  defp object(<<?", rest::binary>>, size, acc) do
    {key, rest} = string_body(rest, size, [])

    case skip_ws(rest) do
      <<?:, rest::binary>> ->
        {val, rest} = value(skip_ws(rest), size)
        acc = Map.put(acc, key, val)

        case skip_ws(rest) do
          <<?,, rest::binary>> -> object_key(skip_ws(rest), size, acc)
          <<?}, rest::binary>> -> {acc, rest}
          rest -> fail(rest, size)
        end

      rest ->
        fail(rest, size)
    end
  end

  defp object(rest, size, _acc), do: fail(rest, size)

  # After a comma: a key must follow (no trailing comma).
  defp object_key(<<?", _::binary>> = rest, size, acc), do: object(rest, size, acc)
  defp object_key(rest, size, _acc), do: fail(rest, size)

  defp array(<<?], rest::binary>>, _size, []), do: {[], rest}

  defp array(data, size, acc) do
    {val, rest} = value(data, size)

    case skip_ws(rest) do
      <<?,, rest::binary>> -> array(skip_ws(rest), size, [val | acc])
      <<?], rest::binary>> -> {Enum.reverse([val | acc]), rest}
      rest -> fail(rest, size)
    end
  end

  defp string_body(<<?", rest::binary>>, _size, acc), do: {IO.iodata_to_binary(acc), rest}

  defp string_body(<<?\\, rest::binary>> = data, size, acc) do
    case rest do
      <<?", rest::binary>> -> string_body(rest, size, [acc, ?"])
      <<?\\, rest::binary>> -> string_body(rest, size, [acc, ?\\])
      <<?/, rest::binary>> -> string_body(rest, size, [acc, ?/])
      <<?b, rest::binary>> -> string_body(rest, size, [acc, ?\b])
      <<?f, rest::binary>> -> string_body(rest, size, [acc, ?\f])
      <<?n, rest::binary>> -> string_body(rest, size, [acc, ?\n])
      <<?r, rest::binary>> -> string_body(rest, size, [acc, ?\r])
      <<?t, rest::binary>> -> string_body(rest, size, [acc, ?\t])
      <<?u, rest::binary>> -> unicode_escape(rest, data, size, acc)
      _ -> fail(rest, size)
    end
  end

  defp string_body(<<c, rest::binary>>, size, acc) when c >= 0x20 and c < 0x80 do
    string_body(rest, size, [acc, c])
  end

  defp string_body(<<c::utf8, rest::binary>> = data, size, acc) when c >= 0x80 do
    # Literal UTF-8: copy the bytes of this code point.
    len = byte_size(data) - byte_size(rest)
    string_body(rest, size, [acc, binary_part(data, 0, len)])
  end

  defp string_body(rest, size, _acc), do: fail(rest, size)

  defp unicode_escape(rest, escape_start, size, acc) do
    {code, rest} = hex4(rest, size)

    cond do
      code in 0xD800..0xDBFF ->
        case rest do
          <<?\\, ?u, low_data::binary>> ->
            case hex4(low_data, size) do
              {low, rest} when low in 0xDC00..0xDFFF ->
                cp = 0x10000 + (code - 0xD800) * 0x400 + (low - 0xDC00)
                string_body(rest, size, [acc, <<cp::utf8>>])

              _ ->
                fail(rest, size)
            end

          _ ->
            fail(rest, size)
        end

      code in 0xDC00..0xDFFF ->
        fail(escape_start, size)

      true ->
        string_body(rest, size, [acc, <<code::utf8>>])
    end
  end

  defp hex4(<<a, b, c, d, rest::binary>> = data, size) do
    case Integer.parse(<<a, b, c, d>>, 16) do
      {code, ""} when a not in [?+, ?-] -> {code, rest}
      _ -> fail(data, size)
    end
  end

  defp hex4(data, size), do: fail(data, size)

  defp number(data, size) do
    {sign, rest} =
      case data do
        <<?-, rest::binary>> -> {"-", rest}
        _ -> {"", data}
      end

    {int, rest} =
      case rest do
        <<?0, rest::binary>> -> {"0", rest}
        <<c, _::binary>> when c in ?1..?9 -> digits(rest)
        _ -> fail(rest, size)
      end

    {frac, rest} =
      case rest do
        <<?., rest::binary>> -> required_digits(rest, size)
        _ -> {nil, rest}
      end

    {exp, rest} =
      case rest do
        <<e, rest::binary>> when e in [?e, ?E] ->
          {exp_sign, rest} =
            case rest do
              <<s, rest::binary>> when s in [?+, ?-] -> {<<s>>, rest}
              _ -> {"", rest}
            end

          {digits, rest} = required_digits(rest, size)
          {exp_sign <> digits, rest}

        _ ->
          {nil, rest}
      end

    value =
      if frac == nil and exp == nil do
        String.to_integer(sign <> int)
      else
        text = sign <> int <> "." <> (frac || "0") <> "e" <> (exp || "0")

        try do
          :erlang.binary_to_float(text)
        rescue
          ArgumentError -> fail(data, size)
        end
      end

    {value, rest}
  end

  defp required_digits(<<c, _::binary>> = data, _size) when c in ?0..?9, do: digits(data)
  defp required_digits(data, size), do: fail(data, size)

  defp digits(data), do: digits(data, 0, data)

  defp digits(<<c, rest::binary>>, n, orig) when c in ?0..?9, do: digits(rest, n + 1, orig)
  defp digits(rest, n, orig), do: {binary_part(orig, 0, n), rest}
end
