defmodule TartarusDashboard.Term do
  @moduledoc """
  Elixir literal terms typed on the page (`{:ping, 1}`, `[a: 1, b: "x"]`, `%{n: -2.5}`),
  read as data only: the text is parsed (`Code.string_to_quoted/2` with
  `existing_atoms_only: true`, so no atom is made from input) and the parse tree is walked
  by a walker that knows only literals. Nothing is ever evaluated: a call, a variable, an
  operator other than a sign on a number, a sigil, a pin or a module attribute is refused
  with what it was.

      iex> TartarusDashboard.Term.parse("{:ping, 1}")
      {:ok, {:ping, 1}}
      iex> TartarusDashboard.Term.parse(~s(%{"a" => [1, -2.5, nil], b: {:ok, 3, true}}))
      {:ok, %{"a" => [1, -2.5, nil], :b => {:ok, 3, true}}}
      iex> TartarusDashboard.Term.parse("System.halt()")
      {:error, "not a literal term: System.halt() (a call; only numbers, atoms, strings, lists, tuples and maps are read)"}
  """

  @max_bytes 4_096

  @doc """
  Parses `text` as one Elixir literal term: numbers, atoms that exist already, strings,
  charlists, lists, tuples, maps and keyword lists, and module names (`Tartarus.Examples.Echo`)
  that exist. `{:ok, term}` or `{:error, message}`. At most #{@max_bytes} bytes.
  """
  @spec parse(String.t()) :: {:ok, term()} | {:error, String.t()}
  def parse(text) when is_binary(text) and byte_size(text) > @max_bytes,
    do: {:error, "the term is longer than #{@max_bytes} bytes"}

  def parse(text) when is_binary(text) do
    case Code.string_to_quoted(text, existing_atoms_only: true) do
      {:ok, quoted} ->
        try do
          {:ok, literal(quoted)}
        catch
          {:not_literal, what, why} -> {:error, "not a literal term: #{what} (#{why})"}
        end

      {:error, {_meta, "unsafe atom does not exist: ", name}} ->
        {:error,
         "no atom #{name} exists on this node (none is made from input): not a term it knows"}

      {:error, {_meta, message, token}} ->
        {:error, "not an Elixir term: #{message_text(message)}#{token}"}
    end
  rescue
    # An atom that does not exist (`existing_atoms_only`) raises in some positions.
    e -> {:error, "not an Elixir term: #{Exception.message(e)}"}
  end

  defp message_text({a, b}), do: "#{a}#{b}"
  defp message_text(m), do: to_string(m)

  defp literal(x) when is_number(x) or is_atom(x) or is_binary(x), do: x
  defp literal(list) when is_list(list), do: Enum.map(list, &literal/1)
  defp literal({a, b}), do: {literal(a), literal(b)}

  defp literal({:{}, _, elems}) when is_list(elems),
    do: elems |> Enum.map(&literal/1) |> List.to_tuple()

  defp literal({:%{}, _, pairs}) when is_list(pairs),
    do: Map.new(pairs, fn {k, v} -> {literal(k), literal(v)} end)

  defp literal({sign, _, [n]}) when sign in [:-, :+] and is_number(n),
    do: if(sign == :-, do: -n, else: n)

  defp literal({:__aliases__, _, parts} = q) when is_list(parts) do
    if Enum.all?(parts, &is_atom/1) do
      String.to_existing_atom("Elixir." <> Enum.map_join(parts, ".", &Atom.to_string/1))
    else
      refuse(q, "a computed module name")
    end
  rescue
    ArgumentError -> refuse(q, "no such module")
  end

  defp literal({name, _, ctx} = q) when is_atom(name) and is_atom(ctx),
    do: refuse(q, "a variable")

  defp literal({:@, _, _} = q), do: refuse(q, "a module attribute")
  defp literal({:^, _, _} = q), do: refuse(q, "a pin")
  defp literal({:<<>>, _, _} = q), do: refuse(q, "a binary pattern; write a string")
  defp literal({:%, _, _} = q), do: refuse(q, "a struct")
  defp literal({_, _, args} = q) when is_list(args), do: refuse(q, "a call")
  defp literal(q), do: refuse(q, "not data")

  defp refuse(q, why) do
    text = q |> Macro.to_string() |> String.slice(0, 80)

    throw(
      {:not_literal, text,
       why <> "; only numbers, atoms, strings, lists, tuples and maps are read"}
    )
  end
end
