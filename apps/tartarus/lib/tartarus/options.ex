defmodule Tartarus.Options do
  @moduledoc """
  A small validator for keyword options: one schema per function, errors that name the key,
  the expectation and the value, and docs generated from the same schema.

      iex> schema = [hops: [type: :pos_integer, default: 10, doc: "number of hops"]]
      iex> Tartarus.Options.validate([], schema, "bench/1")
      {:ok, [hops: 10]}
      iex> Tartarus.Options.validate([hops: 0], schema, "bench/1")
      {:error, "invalid options given to bench/1 for key :hops: expected a positive integer, got: 0"}
      iex> Tartarus.Options.validate([hop: 1], schema, "bench/1")
      {:error, "invalid options given to bench/1: unknown key :hop, known keys: [:hops]"}
  """

  @typedoc """
  A type in a schema: `:any`, `:atom`, `:boolean`, `:integer`, `:pos_integer`,
  `:non_neg_integer`, `:number`, `:probability` (a number in 0..1), `:timeout`
  (non-negative integer or `:infinity`), `:pos_integer_or_infinity`, `:host`,
  `{:list, type}`, `{:in, values}`, `{:fun, arity}`, `:keyword`, `:string`.
  """
  @type type :: atom() | {:list, type()} | {:in, list()} | {:fun, non_neg_integer()}

  @typedoc "A schema: each key with `:type`, an optional `:default`, `:required` and `:doc`."
  @type schema :: keyword(keyword())

  @doc """
  Validates `opts` against `schema`. Returns the options with defaults filled in, or an
  error message naming `where` (e.g. `"Tartarus.start_host/2"`).
  """
  @spec validate(keyword(), schema(), String.t()) :: {:ok, keyword()} | {:error, String.t()}
  def validate(opts, schema, where) when is_list(opts) do
    if Keyword.keyword?(opts) do
      known = Keyword.keys(schema)

      with :ok <- check_unknown(opts, known, where) do
        Enum.reduce_while(schema, {:ok, []}, fn {key, spec}, {:ok, acc} ->
          case Keyword.fetch(opts, key) do
            {:ok, value} ->
              if valid?(spec[:type], value),
                do: {:cont, {:ok, [{key, value} | acc]}},
                else: {:halt, {:error, message(where, key, spec[:type], value)}}

            :error ->
              cond do
                Keyword.has_key?(spec, :default) ->
                  {:cont, {:ok, [{key, spec[:default]} | acc]}}

                spec[:required] ->
                  {:halt, {:error, "required option #{inspect(key)} not given to #{where}"}}

                true ->
                  {:cont, {:ok, acc}}
              end
          end
        end)
        |> case do
          {:ok, acc} -> {:ok, Enum.reverse(acc)}
          error -> error
        end
      end
    else
      {:error,
       "invalid options given to #{where}: expected a keyword list, got: #{inspect(opts)}"}
    end
  end

  def validate(opts, _schema, where),
    do:
      {:error,
       "invalid options given to #{where}: expected a keyword list, got: #{inspect(opts)}"}

  @doc "Like `validate/3` but raises `ArgumentError`."
  @spec validate!(keyword(), schema(), String.t()) :: keyword()
  def validate!(opts, schema, where) do
    case validate(opts, schema, where) do
      {:ok, opts} -> opts
      {:error, message} -> raise ArgumentError, message
    end
  end

  @doc "Markdown documentation of a schema, for `@doc` strings."
  @spec docs(schema()) :: String.t()
  def docs(schema) do
    Enum.map_join(schema, "\n", fn {key, spec} ->
      default =
        if Keyword.has_key?(spec, :default),
          do: " Defaults to `#{inspect(spec[:default])}`.",
          else: ""

      required = if spec[:required], do: " Required.", else: ""

      "  * `#{inspect(key)}` - #{String.trim_trailing(spec[:doc] || "", ".")}.#{required}#{default}"
    end)
  end

  defp check_unknown(opts, known, where) do
    case Enum.find(Keyword.keys(opts), &(&1 not in known)) do
      nil ->
        :ok

      key ->
        {:error,
         "invalid options given to #{where}: unknown key #{inspect(key)}, known keys: #{inspect(known)}"}
    end
  end

  defp message(where, key, type, value) do
    "invalid options given to #{where} for key #{inspect(key)}: expected #{describe(type)}, got: #{inspect(value)}"
  end

  @doc false
  def valid?(:any, _), do: true
  def valid?(:atom, v), do: is_atom(v)
  def valid?(:boolean, v), do: is_boolean(v)
  def valid?(:integer, v), do: is_integer(v)
  def valid?(:pos_integer, v), do: is_integer(v) and v > 0
  def valid?(:non_neg_integer, v), do: is_integer(v) and v >= 0
  def valid?(:number, v), do: is_number(v)
  def valid?(:probability, v), do: is_number(v) and v >= 0 and v <= 1
  def valid?(:timeout, v), do: v == :infinity or (is_integer(v) and v >= 0)
  def valid?(:pos_integer_or_infinity, v), do: v == :infinity or (is_integer(v) and v > 0)
  def valid?(:string, v), do: is_binary(v)
  def valid?(:keyword, v), do: is_list(v) and Keyword.keyword?(v)
  def valid?(:host, v), do: Tartarus.Host.address?(v)
  def valid?({:list, t}, v), do: is_list(v) and Enum.all?(v, &valid?(t, &1))
  def valid?({:in, values}, v), do: v in values
  def valid?({:fun, arity}, v), do: is_function(v, arity)
  def valid?(nil, _), do: true

  defp describe(:any), do: "any term"
  defp describe(:atom), do: "an atom"
  defp describe(:boolean), do: "a boolean"
  defp describe(:integer), do: "an integer"
  defp describe(:pos_integer), do: "a positive integer"
  defp describe(:non_neg_integer), do: "a non-negative integer"
  defp describe(:number), do: "a number"
  defp describe(:probability), do: "a number between 0 and 1"
  defp describe(:timeout), do: "a non-negative integer or :infinity"
  defp describe(:pos_integer_or_infinity), do: "a positive integer or :infinity"
  defp describe(:string), do: "a string"
  defp describe(:keyword), do: "a keyword list"
  defp describe(:host), do: "a host (a name, or {name, node})"
  defp describe({:list, :host}), do: "a list of hosts (names, or {name, node})"
  defp describe({:list, t}), do: "a list of #{describe(t)}"
  defp describe({:in, values}), do: "one of #{inspect(values)}"
  defp describe({:fun, arity}), do: "a function of arity #{arity}"
end
