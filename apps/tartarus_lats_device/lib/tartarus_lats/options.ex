defmodule TartarusLats.Options do
  @moduledoc false
  # LATS's one options path: `Tartarus.Options` (types, defaults, unknown keys, docs), plus a
  # `check: name` entry in a key's spec for what a type cannot say (see check/2). Errors name
  # the key, the expectation and the value, in the platform's wording.

  @spec validate!(keyword(), Tartarus.Options.schema(), String.t()) :: keyword()
  def validate!(opts, schema, where) do
    opts = Tartarus.Options.validate!(opts, schema, where)

    Enum.each(schema, fn {key, spec} ->
      with name when name != nil <- spec[:check],
           {:ok, value} <- Keyword.fetch(opts, key),
           {false, expected} <- check(name, value) do
        raise ArgumentError, message(where, key, expected, value)
      end
    end)

    opts
  end

  @spec message(String.t(), atom(), String.t(), term()) :: String.t()
  def message(where, key, expected, value),
    do:
      "invalid options given to #{where} for key #{inspect(key)}: expected #{expected}, got: #{inspect(value)}"

  defp check(:positive, v), do: {is_number(v) and v > 0, "a positive number"}
  defp check(:non_negative, v), do: {is_number(v) and v >= 0, "a non-negative number"}
  defp check(:at_least_zero, v), do: {is_number(v) and v >= 0, "a number >= 0"}
  defp check(:odd, v), do: {is_integer(v) and v > 0 and rem(v, 2) == 1, "an odd positive integer"}
  defp check(:probability, v), do: {is_number(v) and v >= 0 and v <= 1, "a probability in 0..1"}

  defp check(:db_range, v),
    do:
      {match?({lo, hi} when is_number(lo) and is_number(hi) and lo <= hi, v),
       "a {low, high} range of dB"}

  defp check({:struct, module, what}, v), do: {is_struct(v, module), what}
end
