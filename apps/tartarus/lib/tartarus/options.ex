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

  ## One dialect for the umbrella

  The platform's constructors (`Tartarus.Options.Platform`), the admission policy
  (`Tartarus.Security.Admission`), the emulator and the applications all describe their
  options this way, so every error reads the same. A module keeps its schema in an
  attribute, documents it from there and validates with it:

      @schema [
        hosts: [type: :pos_integer, default: 16, doc: "hosts in the topology"],
        limits: [type: {:keyword, [max: [type: :pos_integer, default: 5]]}, default: []]
      ]

      @doc \"""
      Starts a run. Options:

      \#{Tartarus.Options.docs(@schema)}
      \"""
      def start(opts), do: Tartarus.Options.validate(opts, @schema, "MyApp.start/1")

  A mix task reads its flags and defaults from the same schema (the tooling app's CLI
  helpers do it); `defaults/1` gives the defaults to whoever shows them.
  """

  @typedoc """
  A type in a schema: `:any`, `:atom`, `:boolean`, `:integer`, `:pos_integer`,
  `:non_neg_integer`, `:number`, `:probability` (a number in 0..1), `{:range, lo, hi}` (a
  number from `lo` to `hi`, both included: finite, so `1.0e308` is refused where a
  duration is asked for), `:timeout`
  (non-negative integer or `:infinity`), `:pos_integer_or_infinity`, `:host`, `:map`,
  `:string`, `:keyword`, `{:list, type}`, `{:in, values}`, `{:fun, arity}`,
  `{:tuple, [type]}` (a tuple of that size, element by element), `{:or, [type]}` (any of the
  types), `{:struct, module}`, `{:custom, predicate}` (a 1-arity function that says whether
  a value is valid; give the spec an `:expected` to say what it wants), or
  `{:keyword, schema}`: a nested keyword list validated against its own schema
  (defaults filled in; errors name the key path, e.g. `[:admission, :max_hops]`).
  """
  @type type ::
          atom()
          | {:list, type()}
          | {:in, list()}
          | {:range, number(), number()}
          | {:fun, non_neg_integer()}
          | {:tuple, [type()]}
          | {:or, [type()]}
          | {:struct, module()}
          | {:custom, (term() -> boolean())}
          | {:keyword, schema()}

  @typedoc """
  A schema: each key with `:type`, an optional `:default`, `:required`, `:doc`, and
  `:expected` (the words that replace the type's description in errors).
  """
  @type schema :: keyword(keyword())

  @doc """
  Validates `opts` against `schema`. Returns the options with defaults filled in (in the
  schema's order), or an error message naming `where` (e.g. `"Tartarus.start_host/2"`),
  the key, what was expected and what arrived.

      iex> schema = [limits: [type: {:keyword, [max: [type: :pos_integer, default: 5]]}, default: []]]
      iex> Tartarus.Options.validate([], schema, "f/1")
      {:ok, [limits: [max: 5]]}
      iex> Tartarus.Options.validate([limits: [max: 0]], schema, "f/1")
      {:error, "invalid options given to f/1 for key [:limits, :max]: expected a positive integer, got: 0"}
  """
  @spec validate(keyword(), schema(), String.t()) :: {:ok, keyword()} | {:error, String.t()}
  def validate(opts, schema, where), do: validate(opts, schema, where, [])

  defp validate(opts, schema, where, path) do
    if is_list(opts) and Keyword.keyword?(opts) do
      known = Keyword.keys(schema)

      with :ok <- check_unknown(opts, known, where, path) do
        Enum.reduce_while(schema, {:ok, []}, fn {key, spec}, {:ok, acc} ->
          case Keyword.fetch(opts, key) do
            {:ok, value} ->
              case check_value(spec, value, where, path ++ [key]) do
                {:ok, value} -> {:cont, {:ok, [{key, value} | acc]}}
                error -> {:halt, error}
              end

            :error ->
              cond do
                Keyword.has_key?(spec, :default) ->
                  case {spec[:type], spec[:default]} do
                    {{:keyword, sub}, default} when is_list(default) ->
                      case validate(default, sub, where, path ++ [key]) do
                        {:ok, value} -> {:cont, {:ok, [{key, value} | acc]}}
                        error -> {:halt, error}
                      end

                    _ ->
                      {:cont, {:ok, [{key, spec[:default]} | acc]}}
                  end

                spec[:required] ->
                  {:halt,
                   {:error, "required option #{key_name(path ++ [key])} not given to #{where}"}}

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
      {:error, "#{prefix(where, path)}: expected a keyword list, got: #{inspect(opts)}"}
    end
  end

  defp check_value(spec, value, where, path) do
    case spec[:type] do
      {:keyword, sub} ->
        validate(value, sub, where, path)

      type ->
        if valid?(type, value),
          do: {:ok, value},
          else: {:error, message(where, path, spec[:expected] || describe(type), value)}
    end
  end

  @doc "Like `validate/3` but raises `ArgumentError`."
  @spec validate!(keyword(), schema(), String.t()) :: keyword()
  def validate!(opts, schema, where) do
    case validate(opts, schema, where) do
      {:ok, opts} -> opts
      {:error, message} -> raise ArgumentError, message
    end
  end

  @doc """
  The defaults of a schema, in its order (keys without a default are left out), for callers
  that show or reuse them, such as a mix task driving a scenario.

      iex> Tartarus.Options.defaults(seed: [type: :integer, default: 1], out: [type: :string])
      [seed: 1]
  """
  @spec defaults(schema()) :: keyword()
  def defaults(schema) do
    for {key, spec} <- schema, Keyword.has_key?(spec, :default) do
      case {spec[:type], spec[:default]} do
        {{:keyword, sub}, default} when is_list(default) ->
          {key, Keyword.merge(defaults(sub), default)}

        {_, default} ->
          {key, default}
      end
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

      nested =
        case spec[:type] do
          {:keyword, sub} -> "\n" <> String.replace(docs(sub), ~r/^/m, "    ")
          _ -> ""
        end

      doc =
        case String.trim_trailing(spec[:doc] || "", ".") do
          "" -> ""
          text -> " - #{text}."
        end

      "  * `#{inspect(key)}`#{doc}#{required}#{default}" <> nested
    end)
  end

  defp check_unknown(opts, known, where, path) do
    case Enum.find(Keyword.keys(opts), &(&1 not in known)) do
      nil ->
        :ok

      key ->
        {:error,
         "#{prefix(where, path)}: unknown key #{inspect(key)}, known keys: #{inspect(known)}"}
    end
  end

  defp prefix(where, []), do: "invalid options given to #{where}"
  defp prefix(where, path), do: "invalid options given to #{where} for key #{key_name(path)}"

  defp key_name([key]), do: inspect(key)
  defp key_name(path), do: inspect(path)

  defp message(where, path, expected, value) do
    "#{prefix(where, path)}: expected #{expected}, got: #{inspect(value)}"
  end

  @doc """
  True if `value` is of `type`.

      iex> Tartarus.Options.valid?({:list, :host}, [:a, {:b, :"n@h"}])
      true
  """
  @spec valid?(type(), term()) :: boolean()
  def valid?(:any, _), do: true
  def valid?(:atom, v), do: is_atom(v)
  def valid?(:boolean, v), do: is_boolean(v)
  def valid?(:integer, v), do: is_integer(v)
  def valid?(:pos_integer, v), do: is_integer(v) and v > 0
  def valid?(:non_neg_integer, v), do: is_integer(v) and v >= 0
  def valid?(:number, v), do: is_number(v)
  def valid?(:probability, v), do: is_number(v) and v >= 0 and v <= 1
  def valid?({:range, lo, hi}, v), do: is_number(v) and v >= lo and v <= hi
  def valid?(:timeout, v), do: v == :infinity or (is_integer(v) and v >= 0)
  def valid?(:pos_integer_or_infinity, v), do: v == :infinity or (is_integer(v) and v > 0)
  def valid?(:string, v), do: is_binary(v)
  def valid?(:keyword, v), do: is_list(v) and Keyword.keyword?(v)
  def valid?(:map, v), do: is_map(v)
  def valid?(:host, v), do: Tartarus.Host.address?(v)
  def valid?({:list, t}, v), do: is_list(v) and Enum.all?(v, &valid?(t, &1))
  def valid?({:in, values}, v), do: v in values
  def valid?({:fun, arity}, v), do: is_function(v, arity)

  def valid?({:tuple, ts}, v),
    do:
      is_tuple(v) and tuple_size(v) == length(ts) and
        Enum.all?(Enum.zip(ts, Tuple.to_list(v)), fn {t, x} -> valid?(t, x) end)

  def valid?({:or, ts}, v), do: Enum.any?(ts, &valid?(&1, v))
  def valid?({:struct, module}, v), do: is_struct(v, module)
  def valid?({:custom, predicate}, v), do: predicate.(v) == true
  def valid?({:keyword, schema}, v), do: match?({:ok, _}, validate(v, schema, ""))
  def valid?(nil, _), do: true

  @doc """
  The words an error uses for what `type` expects.

      iex> Tartarus.Options.describe({:or, [{:in, [:infinity]}, {:tuple, [:pos_integer, :pos_integer]}]})
      "one of [:infinity] or a tuple {a positive integer, a positive integer}"
  """
  @spec describe(type()) :: String.t()
  def describe(:any), do: "any term"
  def describe(:atom), do: "an atom"
  def describe(:boolean), do: "a boolean"
  def describe(:integer), do: "an integer"
  def describe(:pos_integer), do: "a positive integer"
  def describe(:non_neg_integer), do: "a non-negative integer"
  def describe(:number), do: "a number"
  def describe(:probability), do: "a number between 0 and 1"
  def describe({:range, lo, hi}), do: "a number from #{lo} to #{hi}"
  def describe(:timeout), do: "a non-negative integer or :infinity"
  def describe(:pos_integer_or_infinity), do: "a positive integer or :infinity"
  def describe(:string), do: "a string"
  def describe(:keyword), do: "a keyword list"
  def describe(:host), do: "a host (a name, or {name, node})"
  def describe({:list, :host}), do: "a list of hosts (names, or {name, node})"
  def describe({:list, t}), do: "a list of #{describe(t)}"
  def describe({:in, values}), do: "one of #{inspect(values)}"
  def describe({:fun, arity}), do: "a function of arity #{arity}"
  def describe(:map), do: "a map"
  def describe({:tuple, ts}), do: "a tuple {#{Enum.map_join(ts, ", ", &describe/1)}}"
  def describe({:or, ts}), do: Enum.map_join(ts, " or ", &describe/1)
  def describe({:keyword, _}), do: "a keyword list"
  def describe({:struct, module}), do: "a %#{inspect(module)}{}"
  def describe({:custom, _}), do: "a valid value"
  def describe(nil), do: "any term"
end
