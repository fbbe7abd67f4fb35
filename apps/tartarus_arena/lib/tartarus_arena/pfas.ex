defmodule TartarusArena.PFAs do
  @moduledoc """
  The eight path-following algorithms of Table 6.4 (`TartarusArena.PFA` is their
  behaviour): the list, and their names "A1" .. "A8".
  """

  @all [
    TartarusArena.PFA.A1,
    TartarusArena.PFA.A2,
    TartarusArena.PFA.A3,
    TartarusArena.PFA.A4,
    TartarusArena.PFA.A5,
    TartarusArena.PFA.A6,
    TartarusArena.PFA.A7,
    TartarusArena.PFA.A8
  ]

  @doc """
  The eight PFAs, A1 to A8.

      iex> length(TartarusArena.PFAs.all())
      8
  """
  @spec all() :: [TartarusArena.PFA.t()]
  def all, do: @all

  @doc """
  A PFA's short name, `"A1"` .. `"A8"`.

      iex> TartarusArena.PFAs.name(TartarusArena.PFA.A4)
      "A4"
  """
  @spec name(TartarusArena.PFA.t()) :: String.t()
  def name(module), do: module |> Module.split() |> List.last()

  @doc """
  The PFA module named `"A1"` .. `"A8"` (or `:a1` ..), or nil.

      iex> TartarusArena.PFAs.by_name("A2")
      TartarusArena.PFA.A2
  """
  @spec by_name(String.t() | atom()) :: TartarusArena.PFA.t() | nil
  def by_name(name) do
    n = name |> to_string() |> String.upcase()
    Enum.find(@all, &(name(&1) == n))
  end
end
