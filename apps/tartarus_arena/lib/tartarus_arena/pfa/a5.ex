defmodule TartarusArena.PFA.A5 do
  @moduledoc """
  A5 (Table 6.4): proportional-derivative (PD) control on the deviation `e = (right - left) / 48` (in [-1, 1],
  positive when the line drifts under the left sensor): `u = kp e + kd de/dt`, wheels
  `{base - u, base + u}` clipped to [-1, 1]. Defaults: kp 1.4, ki 0.0, kd 0.03, base 0.75.

      iex> s = TartarusArena.PFA.A5.init([])
      iex> {{l, r}, _} = TartarusArena.PFA.A5.control({36, 60}, 0.02, s)
      iex> l < r
      true
  """
  @behaviour TartarusArena.PFA

  @impl true
  @doc "State: gains, cruise speed, integral and last error."
  def init(opts) do
    %{
      kp: Keyword.get(opts, :kp, 1.4),
      ki: Keyword.get(opts, :ki, 0.0),
      kd: Keyword.get(opts, :kd, 0.03),
      base: Keyword.get(opts, :base, 0.75),
      limit: Keyword.get(opts, :integral_limit, 0.3),
      integral: 0.0,
      last: nil
    }
  end

  @impl true
  @doc "One proportional-derivative (PD) step."
  def control({l, r}, dt, s) do
    e = max(-1.0, min(1.0, (r - l) / 48))
    integral = max(-s.limit, min(s.limit, s.integral + e * dt))
    de = if s.last == nil or dt <= 0, do: 0.0, else: (e - s.last) / dt
    u = s.kp * e + s.ki * integral + s.kd * de
    cmd = {max(-1.0, min(1.0, s.base - u)), max(-1.0, min(1.0, s.base + u))}
    {cmd, %{s | integral: integral, last: e}}
  end

  @impl true
  @doc "Table 6.4's description."
  def strategy, do: "Proportional and Derivative (PD) control"
end
