defmodule TartarusArena.PFA.A4 do
  @moduledoc """
  A4 (Table 6.4): proportional control. The deviation `e = (right - left) / 48` (the
  difference of the two readings over the floor-to-tape contrast, in [-1, 1]; positive
  when the line drifts under the left sensor) slows the motor on that side in proportion:
  `u = kp * e` (default `kp` 2.0), left speed `base * (1 - u)` when `u > 0`, right speed
  `base * (1 + u)` when `u < 0`, clipped to [-1, 1]; `base` defaults to 1.0.

      iex> s = TartarusArena.PFA.A4.init([])
      iex> {cmd, _} = TartarusArena.PFA.A4.control({48, 60}, 0.02, s)
      iex> cmd
      {0.5, 1.0}
  """
  @behaviour TartarusArena.PFA

  @impl true
  @doc "State: the gain and the cruise speed."
  def init(opts), do: %{kp: Keyword.get(opts, :kp, 2.0), base: Keyword.get(opts, :base, 1.0)}

  @impl true
  @doc "Slows one motor in proportion to the deviation."
  def control({l, r}, _dt, s) do
    u = s.kp * max(-1.0, min(1.0, (r - l) / 48))

    cmd =
      if u > 0,
        do: {max(-1.0, s.base * (1 - u)), s.base},
        else: {s.base, max(-1.0, s.base * (1 + u))}

    {cmd, s}
  end

  @impl true
  @doc "Table 6.4's description."
  def strategy,
    do:
      "Based on the deviation in the light sensor value from the edge of the path, proportionally decrease the speed of either of the motors"
end
