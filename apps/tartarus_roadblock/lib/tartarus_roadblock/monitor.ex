defmodule TartarusRoadblock.Monitor do
  @moduledoc """
  The monitoring node's static agent (the Pi with a webcam beside the path). On
  `{:blocked, report}` from a robot it takes a snapshot with its host's camera
  (`Tartarus.Agent.read(:camera, :snapshot)`, a PNG) and forwards it, with the report, to
  the administrator's agent as `{:snapshot, png, report}`.

  Args: `%{admin: agent_ref}`.
  """
  use Tartarus.Agent

  @impl true
  @doc "Waits for reports."
  def init(%{admin: _} = args), do: {:stay, Map.put(args, :snapshots, 0)}

  @impl true
  @doc "`{:blocked, report}`: snapshot and forward."
  def handle_message({:blocked, report}, _from, s) do
    {:ok, png} = Tartarus.Agent.read(:camera, :snapshot)
    report = Map.put(report, :monitor, Tartarus.Agent.host())
    Tartarus.cast(s.admin, {:snapshot, png, report})
    {:stay, %{s | snapshots: s.snapshots + 1}}
  end

  def handle_message(_other, _from, s), do: {:stay, s}
end
