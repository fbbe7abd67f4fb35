defmodule TartarusTools.Series do
  @moduledoc """
  Named time series keyed by step number: the pure data part of a scenario's step log.

  The thesis reports its experiments in step counts; a run records values per step and
  writes them out at the end as CSV rows (one column per series) and chart series.

      iex> alias TartarusTools.Series
      iex> s = Series.new() |> Series.record(:clones, 1, 4) |> Series.record(:clones, 2, 6)
      iex> s = Series.record(s, :apoptosis, 2, 1)
      iex> {Series.header(s), Series.to_rows(s)}
      {["step", "apoptosis", "clones"], [[1, nil, 4], [2, 1, 6]]}

  Recording the same name and step twice keeps the last value. Names may be atoms or
  strings; they are ordered by their string form.
  """

  defstruct data: %{}

  @type name :: atom | String.t()
  @type t :: %__MODULE__{data: %{optional(name) => %{optional(integer) => term}}}

  @doc "An empty set of series."
  @spec new() :: t
  def new, do: %__MODULE__{}

  @doc """
  Records `value` for series `name` at `step`.

  ## Examples

      iex> TartarusTools.Series.new() |> TartarusTools.Series.record("x", 0, 1.5) |> TartarusTools.Series.points("x")
      [{0, 1.5}]
  """
  @spec record(t, name, integer, term) :: t
  def record(%__MODULE__{data: data} = s, name, step, value)
      when (is_atom(name) or is_binary(name)) and is_integer(step) do
    %{s | data: Map.update(data, name, %{step => value}, &Map.put(&1, step, value))}
  end

  @doc """
  Series names, sorted by their string form.

  ## Examples

      iex> TartarusTools.Series.new() |> TartarusTools.Series.record(:b, 1, 0) |> TartarusTools.Series.record("a", 1, 0) |> TartarusTools.Series.names()
      ["a", :b]
  """
  @spec names(t) :: [name]
  def names(%__MODULE__{data: data}), do: data |> Map.keys() |> Enum.sort_by(&to_string/1)

  @doc """
  The `{step, value}` points of one series in step order (`[]` if unknown).

  ## Examples

      iex> TartarusTools.Series.new() |> TartarusTools.Series.record(:a, 5, 1) |> TartarusTools.Series.record(:a, 2, 0) |> TartarusTools.Series.points(:a)
      [{2, 0}, {5, 1}]
  """
  @spec points(t, name) :: [{integer, term}]
  def points(%__MODULE__{data: data}, name), do: data |> Map.get(name, %{}) |> Enum.sort()

  @doc """
  The CSV header matching `to_rows/1`: `"step"` then the names as strings.

  ## Examples

      iex> TartarusTools.Series.new() |> TartarusTools.Series.header()
      ["step"]
  """
  @spec header(t) :: [String.t()]
  def header(%__MODULE__{} = s), do: ["step" | Enum.map(names(s), &to_string/1)]

  @doc """
  One row per step that has any value, in step order: `[step, value_of_each_name...]`, with
  `nil` where a series has no value at that step.

  ## Examples

      iex> TartarusTools.Series.new() |> TartarusTools.Series.to_rows()
      []
  """
  @spec to_rows(t) :: [[term]]
  def to_rows(%__MODULE__{data: data} = s) do
    names = names(s)

    data
    |> Map.values()
    |> Enum.flat_map(&Map.keys/1)
    |> Enum.uniq()
    |> Enum.sort()
    |> Enum.map(fn step -> [step | Enum.map(names, &get_in(data, [&1, step]))] end)
  end

  @doc """
  Series in the shape `TartarusTools.SVG.line_chart/2` takes, numeric values only.

  ## Examples

      iex> TartarusTools.Series.new() |> TartarusTools.Series.record(:a, 1, 2) |> TartarusTools.Series.to_chart()
      [%{name: "a", points: [{1, 2}]}]
  """
  @spec to_chart(t) :: [%{name: String.t(), points: [{integer, number}]}]
  def to_chart(%__MODULE__{} = s) do
    Enum.map(names(s), fn name ->
      %{name: to_string(name), points: for({x, y} <- points(s, name), is_number(y), do: {x, y})}
    end)
  end
end
