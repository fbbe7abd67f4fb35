defmodule TartarusEmu.Walker do
  @moduledoc """
  The agent of the walk scenario (`TartarusEmu.Walk`): on each step it makes one move with
  its strategy (`:random` or `:conscientious`) and reports where it is.

  Its state is `%{coord: pid, strategy: strategy, step: n}`. The step signal
  `{:emu_step, step}` arrives as a plain message (`TartarusEmu.Network.broadcast/2`);
  after the move (or the failed move) the walker sends
  `{:emu_walked, step, host, :moved | :failed}` to `coord`; a walker with `trace: true` in
  its state (the walk's first agent) first sends `{:emu_traced, step, host}` for each move,
  the hop its walk figure draws. Its random choices use its own
  seeded random state (`Tartarus.create_agent/4`'s `seed:`), so its walk is the same on
  every run with the same seed and the same network.
  """
  use Tartarus.Agent

  @impl true
  def init(state), do: {:stay, state}

  @impl true
  def handle_info({:emu_step, step}, s) when step > s.step,
    do: {:move, s.strategy, %{s | step: step}}

  def handle_info(_other, s), do: {:stay, s}

  @impl true
  def handle_arrival(ctx, s) do
    if Map.get(s, :trace), do: send(s.coord, {:emu_traced, s.step, ctx.host})
    send(s.coord, {:emu_walked, s.step, ctx.host, :moved})
    {:stay, s}
  end

  @impl true
  def handle_move_failed(_dest, _reason, ctx, s) do
    send(s.coord, {:emu_walked, s.step, ctx.host, :failed})
    {:stay, s}
  end
end
