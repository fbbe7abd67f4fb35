defmodule TartarusArena.PFA.A2 do
  @moduledoc """
  A2 (Table 6.4): if both sensors read white, full speed ahead; else run the motors in
  opposite directions (at `spin`, default 0.8 of top speed) so the robot turns on the
  spot towards the black side. Both black (a crossing, or the
  tip of a sharp corner) goes straight.

      iex> s = TartarusArena.PFA.A2.init([])
      iex> {cmd, _} = TartarusArena.PFA.A2.control({20, 60}, 0.02, s)
      iex> cmd
      {-0.8, 0.8}
  """
  @behaviour TartarusArena.PFA

  @impl true
  @doc "State: the black threshold and the spin speed."
  def init(opts),
    do: %{
      threshold: Keyword.get(opts, :threshold, 36),
      spin: Keyword.get(opts, :spin, 0.8)
    }

  @impl true
  @doc "Full speed on white; spin in place towards the black side."
  def control({l, r}, _dt, s) do
    cmd =
      case {l < s.threshold, r < s.threshold} do
        {true, false} -> {-s.spin, s.spin}
        {false, true} -> {s.spin, -s.spin}
        _ -> {1.0, 1.0}
      end

    {cmd, s}
  end

  @impl true
  @doc "Table 6.4's description."
  def strategy,
    do:
      "If both sensors detect white then move straight with maximum speed else move the motors in opposite directions to turn"
end
