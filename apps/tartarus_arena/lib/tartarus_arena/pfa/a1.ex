defmodule TartarusArena.PFA.A1 do
  @moduledoc """
  A1 (Table 6.4): if both sensors read white, full speed ahead; else switch off the motor
  on the side that sees black, so the robot pivots towards the line. When both read
  black (a sharp corner) it keeps turning towards the side that last saw black alone. A reading below `threshold` (default 36, halfway between the
  floor's 60 and the tape's 12) is black.

      iex> s = TartarusArena.PFA.A1.init([])
      iex> {cmd, _} = TartarusArena.PFA.A1.control({20, 60}, 0.02, s)
      iex> cmd
      {0.0, 1.0}
  """
  @behaviour TartarusArena.PFA

  @impl true
  @doc "State: the black threshold and the last side that saw black."
  def init(opts), do: %{threshold: Keyword.get(opts, :threshold, 36), last: :left}

  @impl true
  @doc "Full speed on white; one motor off towards the black side."
  def control({l, r}, _dt, s) do
    case {l < s.threshold, r < s.threshold} do
      {false, false} -> {{1.0, 1.0}, s}
      {true, false} -> {{0.0, 1.0}, %{s | last: :left}}
      {false, true} -> {{1.0, 0.0}, %{s | last: :right}}
      {true, true} when s.last == :left -> {{0.0, 1.0}, s}
      {true, true} -> {{1.0, 0.0}, s}
    end
  end

  @impl true
  @doc "Table 6.4's description."
  def strategy,
    do:
      "If both sensors detect white then move straight with maximum speed else switch off either of the motors to turn"
end
