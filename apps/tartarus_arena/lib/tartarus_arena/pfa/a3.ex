defmodule TartarusArena.PFA.A3 do
  @moduledoc """
  A3 (Table 6.4): steer smoothly by reducing one motor's speed by a fixed amount (`cut`,
  default 0.6 of top speed): the left motor to steer left (left sensor on black), the
  right one to steer right (both black: the side that last saw black alone). Cruises at `base` (default 0.9).

      iex> s = TartarusArena.PFA.A3.init([])
      iex> {cmd, _} = TartarusArena.PFA.A3.control({20, 60}, 0.02, s)
      iex> cmd
      {0.30000000000000004, 0.9}
  """
  @behaviour TartarusArena.PFA

  @impl true
  @doc "State: threshold, cruise speed and the fixed cut."
  def init(opts) do
    %{
      threshold: Keyword.get(opts, :threshold, 36),
      last: :left,
      base: Keyword.get(opts, :base, 0.9),
      cut: Keyword.get(opts, :cut, 0.6)
    }
  end

  @impl true
  @doc "Cruise; cut the speed of the motor on the black side by a fixed amount."
  def control({l, r}, _dt, s) do
    case {l < s.threshold, r < s.threshold} do
      {false, false} -> {{s.base, s.base}, s}
      {true, false} -> {{s.base - s.cut, s.base}, %{s | last: :left}}
      {false, true} -> {{s.base, s.base - s.cut}, %{s | last: :right}}
      {true, true} when s.last == :left -> {{s.base - s.cut, s.base}, s}
      {true, true} -> {{s.base, s.base - s.cut}, s}
    end
  end

  @impl true
  @doc "Table 6.4's description."
  def strategy,
    do:
      "Reduce the speed of the left motor by a fixed amount to steer left and vice-versa for smooth movement"
end
