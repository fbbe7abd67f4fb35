defmodule TartarusEmu.Energy do
  @moduledoc """
  A simple radio energy model: every message costs a fixed amount plus an amount per byte.

      cost (mJ) = messages * per_message + bytes * per_byte

  The defaults are `per_message: 0.2` mJ and `per_byte: 0.002` mJ, the order of magnitude
  of a low-power radio (BLE / 802.15.4) where waking the radio for a packet dominates small
  payloads. They are parameters, not measurements: scenarios that report energy should state
  the parameters used (they are plain data, so put them in the summary).

  Counts are maps `%{key => %{messages: m, bytes: b}}` keyed by host, by link or anything
  else; a missing `:messages` or `:bytes` counts as 0.

      iex> counts = %{{:h1, :h2} => %{messages: 10, bytes: 1000}, {:h2, :h1} => %{messages: 5, bytes: 0}}
      iex> TartarusEmu.Energy.total(counts)
      5.0
      iex> TartarusEmu.Energy.per_host(counts)
      %{h1: 4.0, h2: 1.0}

  `per_host/2` charges each directed link's cost to its sender; pass `receive_share: s` to
  also charge the receiver `s` times the cost (e.g. `1.0` for a radio whose receive costs as
  much as send).
  """

  defstruct per_message: 0.2, per_byte: 0.002

  @typedoc "Model parameters in millijoules."
  @type t :: %__MODULE__{per_message: number, per_byte: number}

  @typedoc "Traffic counts of one host or link."
  @type counts :: %{optional(:messages) => non_neg_integer, optional(:bytes) => non_neg_integer}

  @doc """
  Model parameters from options `:per_message` and `:per_byte` (mJ, non-negative numbers).

  ## Examples

      iex> TartarusEmu.Energy.params()
      %TartarusEmu.Energy{per_message: 0.2, per_byte: 0.002}
      iex> TartarusEmu.Energy.params(per_byte: 0)
      %TartarusEmu.Energy{per_message: 0.2, per_byte: 0}
      iex> TartarusEmu.Energy.params(per_bit: 1)
      ** (ArgumentError) Energy.params/1: unknown option :per_bit, expected :per_message or :per_byte
  """
  @spec params(keyword) :: t
  def params(opts \\ []) do
    Enum.reduce(opts, %__MODULE__{}, fn
      {key, value}, acc when key in [:per_message, :per_byte] ->
        if is_number(value) and value >= 0 do
          Map.put(acc, key, value)
        else
          raise ArgumentError,
                "Energy.params/1: expected #{inspect(key)} to be a non-negative number (mJ), " <>
                  "got: #{inspect(value)}"
        end

      {key, _}, _ ->
        raise ArgumentError,
              "Energy.params/1: unknown option #{inspect(key)}, expected :per_message or :per_byte"
    end)
  end

  @doc """
  Energy in mJ of one count.

  ## Examples

      iex> TartarusEmu.Energy.cost(%{messages: 3, bytes: 100})
      0.8
      iex> TartarusEmu.Energy.cost(%{messages: 1}, TartarusEmu.Energy.params(per_message: 1))
      1.0
  """
  @spec cost(counts, t) :: number
  def cost(counts, params \\ %__MODULE__{}) do
    {messages, bytes} = counts!(counts)
    messages * params.per_message + bytes * params.per_byte
  end

  @doc """
  Energy in mJ per key (per host or per link, whatever the counts are keyed by).

  ## Examples

      iex> TartarusEmu.Energy.costs(%{h1: %{messages: 1, bytes: 0}, h2: %{bytes: 500}})
      %{h1: 0.2, h2: 1.0}
  """
  @spec costs(%{optional(key) => counts}, t) :: %{optional(key) => number} when key: term
  def costs(count_map, params \\ %__MODULE__{}) when is_map(count_map) do
    Map.new(count_map, fn {key, counts} -> {key, cost(counts, params)} end)
  end

  @doc """
  Total energy in mJ over all keys (`0` for no counts).

  ## Examples

      iex> TartarusEmu.Energy.total(%{a: %{messages: 1, bytes: 0}, b: %{messages: 1, bytes: 0}})
      0.4
      iex> TartarusEmu.Energy.total(%{})
      0
  """
  @spec total(%{optional(term) => counts}, t) :: number
  def total(count_map, params \\ %__MODULE__{}) when is_map(count_map) do
    count_map |> Map.values() |> Enum.map(&cost(&1, params)) |> Enum.sum()
  end

  @doc """
  Folds counts of **directed** links `%{{from, to} => counts}` into energy per host: the
  sender pays the cost, the receiver `receive_share` times it (default `0.0`).

  Options: `:params` (a `t:t/0`, default parameters), `:receive_share` (number >= 0).

  ## Examples

      iex> TartarusEmu.Energy.per_host(%{{:a, :b} => %{messages: 1, bytes: 0}}, receive_share: 0.5)
      %{a: 0.2, b: 0.1}
  """
  @spec per_host(%{optional({host, host}) => counts}, keyword) :: %{optional(host) => number}
        when host: term
  def per_host(link_counts, opts \\ []) when is_map(link_counts) do
    params = Keyword.get(opts, :params, %__MODULE__{})
    share = Keyword.get(opts, :receive_share, 0.0)

    if not (is_number(share) and share >= 0) do
      raise ArgumentError,
            "Energy.per_host/2: expected :receive_share to be a non-negative number, got: " <>
              inspect(share)
    end

    Enum.reduce(link_counts, %{}, fn
      {{from, to}, counts}, acc ->
        c = cost(counts, params)
        acc = Map.update(acc, from, c, &(&1 + c))
        if share > 0, do: Map.update(acc, to, c * share, &(&1 + c * share)), else: acc

      {key, _}, _ ->
        raise ArgumentError,
              "Energy.per_host/2: expected link keys {from, to}, got: #{inspect(key)}"
    end)
  end

  defp counts!(%{} = counts) do
    messages = Map.get(counts, :messages, 0)
    bytes = Map.get(counts, :bytes, 0)

    if is_integer(messages) and messages >= 0 and is_integer(bytes) and bytes >= 0 do
      {messages, bytes}
    else
      bad!(counts)
    end
  end

  defp counts!(other), do: bad!(other)

  defp bad!(counts) do
    raise ArgumentError,
          "Energy: expected counts %{messages: non_neg_integer, bytes: non_neg_integer}, got: " <>
            inspect(counts)
  end
end
