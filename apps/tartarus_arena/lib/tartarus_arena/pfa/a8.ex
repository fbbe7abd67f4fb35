defmodule TartarusArena.PFA.A8 do
  @moduledoc """
  A8 (Table 6.4): A1 with one more case: when both sensors have read white for longer than
  `lost_after` (default 0.35 s) since one of them last saw black, the robot takes a sharp
  turn (spins at `spin`, default 0.8) towards the side where it last saw the line, until a
  sensor finds black again. On a well-aligned straight this costs a small search wiggle;
  after an overshoot at a sharp corner it brings the robot back.

      iex> s = TartarusArena.PFA.A8.init([])
      iex> {cmd, s} = TartarusArena.PFA.A8.control({20, 60}, 0.02, s)
      iex> cmd
      {0.0, 1.0}
      iex> {_, s} = Enum.reduce(1..20, {nil, s}, fn _, {_, s} -> TartarusArena.PFA.A8.control({60, 60}, 0.02, s) end)
      iex> elem(TartarusArena.PFA.A8.control({60, 60}, 0.02, s), 0)
      {-0.8, 0.8}
  """
  @behaviour TartarusArena.PFA

  @impl true
  @doc "State: threshold, the lost delay, spin speed, last side seen, time since black."
  def init(opts) do
    %{
      threshold: Keyword.get(opts, :threshold, 36),
      lost_after: Keyword.get(opts, :lost_after, 0.35),
      spin: Keyword.get(opts, :spin, 0.8),
      last: :left,
      white_for: 0.0
    }
  end

  @impl true
  @doc "A1, plus a sharp turn towards the last side seen when the line is lost."
  def control({l, r}, dt, s) do
    case {l < s.threshold, r < s.threshold} do
      {true, false} ->
        {{0.0, 1.0}, %{s | last: :left, white_for: 0.0}}

      {false, true} ->
        {{1.0, 0.0}, %{s | last: :right, white_for: 0.0}}

      {true, true} when l <= r ->
        {{0.0, 1.0}, %{s | last: :left, white_for: 0.0}}

      {true, true} ->
        {{1.0, 0.0}, %{s | last: :right, white_for: 0.0}}

      {false, false} ->
        s = %{s | white_for: s.white_for + dt}

        cond do
          s.white_for < s.lost_after -> {{1.0, 1.0}, s}
          s.last == :left -> {{-s.spin, s.spin}, s}
          true -> {{s.spin, -s.spin}, s}
        end
    end
  end

  @impl true
  @doc "Table 6.4's description."
  def strategy,
    do:
      "Same as A1 but has an extra case which checks whether both the sensors are away from the black path and takes a sharp turn"
end
