defmodule TartarusArena.DocTest do
  use ExUnit.Case, async: true

  doctest TartarusArena
  doctest TartarusArena.World
  doctest TartarusArena.Paths
  doctest TartarusArena.PFA
  doctest TartarusArena.PFAs
  doctest TartarusArena.PFA.A1
  doctest TartarusArena.PFA.A2
  doctest TartarusArena.PFA.A3
  doctest TartarusArena.PFA.A4
  doctest TartarusArena.PFA.A5
  doctest TartarusArena.PFA.A6
  doctest TartarusArena.PFA.A7
  doctest TartarusArena.PFA.A8
  doctest TartarusArena.Run
  doctest TartarusArena.Server
  doctest TartarusArena.Render
  doctest TartarusArena.PNG
end
