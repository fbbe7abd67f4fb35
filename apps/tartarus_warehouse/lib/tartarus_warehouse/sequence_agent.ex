defmodule TartarusWarehouse.SequenceAgent do
  @moduledoc """
  The sequence agent of on-the-fly programming (thesis §4.5.4, `μ_seq`): it migrates
  among the robots and writes one change (`{:insert, after_task, task}` or
  `{:delete, task}`) into every robot's state-transition database
  (`TartarusWarehouse.Robot`), with every change the distributor made before it (numbered:
  a robot applies those it missed, in order), then terminates, telling the owner
  `{:warehouse_sequence_done, change, time_us}`.
  """
  use Tartarus.Agent

  alias Tartarus.Agent
  alias Tartarus.Clock

  @doc false
  @impl true
  def init(args), do: {:move, strategy(args), Map.put(args, :left, args.all)}

  @doc false
  @impl true
  def handle_arrival(_ctx, s) do
    here = Agent.host()

    s =
      if MapSet.member?(s.left, here) and Agent.write(:robot, {:db, s.changes}) == :ok,
        do: %{s | left: MapSet.delete(s.left, here)},
        else: s

    if MapSet.size(s.left) == 0 do
      if s.owner,
        do: send(s.owner, {:warehouse_sequence_done, s.change, Clock.system_time(:microsecond)})

      {:stop, :normal, s}
    else
      {:move, strategy(s), s}
    end
  end

  @doc false
  @impl true
  def handle_move_failed(_dest, _reason, _ctx, s) do
    Clock.send_after(self(), :roam, 5)
    {:stay, s}
  end

  @doc false
  @impl true
  def handle_info(:roam, s), do: {:move, strategy(s), s}
  def handle_info(_msg, s), do: {:stay, s}

  defp strategy(s), do: {:strategy, TartarusWarehouse.Roam, s.robots}
end
