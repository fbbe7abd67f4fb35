defmodule TartarusArena.PFA do
  @moduledoc """
  Path-following algorithms (PFAs), Table 6.4 of the thesis: the behaviour and the list.

  A PFA is a controller for a robot with two downward light sensors straddling a black line
  (see `TartarusArena.World`: 60 on the floor, 12 on the tape; both read white when the
  robot is centred). Each step it gets the two readings and the step length and returns a
  wheel command `{left, right}` in [-1, 1] (fractions of the top speed):

  | PFA | module | strategy |
  |---|---|---|
  | A1 | `TartarusArena.PFA.A1` | bang-bang: both white, full speed; else switch one motor off to turn |
  | A2 | `TartarusArena.PFA.A2` | bang-bang: both white, full speed; else motors in opposite directions (spin) |
  | A3 | `TartarusArena.PFA.A3` | reduce one motor's speed by a fixed amount to steer smoothly |
  | A4 | `TartarusArena.PFA.A4` | proportional: slow one motor in proportion to the deviation |
  | A5 | `TartarusArena.PFA.A5` | proportional-derivative (PD) |
  | A6 | `TartarusArena.PFA.A6` | proportional-integral (PI) |
  | A7 | `TartarusArena.PFA.A7` | proportional-integral-derivative (PID) |
  | A8 | `TartarusArena.PFA.A8` | A1 plus a sharp turn towards the last side seen when both sensors lost the line |

  Each module is self-contained (it calls nothing but Kernel and `:math`), so an agent can
  carry it as code (`Tartarus.Agent.add_module/1`) and run it on whichever robot host it
  reaches. `TartarusArena.PFAs` lists them; `TartarusArena.Run` drives robots with PFAs over paths and measures them.
  """

  @typedoc "A PFA module."
  @type t :: module()

  @doc "The controller's initial state; `opts` may override its gains."
  @callback init(opts :: keyword()) :: term()

  @doc "One control step: line readings `{left, right}` (0..100), step `dt` (s), state."
  @callback control({number(), number()}, dt :: float(), state :: term()) ::
              {{float(), float()}, term()}

  @doc "Table 6.4's one-line description of the strategy."
  @callback strategy() :: String.t()
end
