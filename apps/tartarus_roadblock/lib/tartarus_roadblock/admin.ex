defmodule TartarusRoadblock.Admin do
  @moduledoc """
  The administrator's inbox: a static agent on the administrator's host. A snapshot that
  arrives (`{:snapshot, png, report}`) is kept in the host's store (`:snapshot`,
  `:report`) and shown to the administrator: sent to the process that watches the run
  (`watcher`, the scenario's driver) as `{:roadblock_snapshot, png, report}`. The
  administrator then releases the rescue agent (`TartarusRoadblock.release_rescue/1`).

  Args: `%{watcher: pid}`.
  """
  use Tartarus.Agent

  @impl true
  @doc "Waits for snapshots."
  def init(%{watcher: pid} = args) when is_pid(pid), do: {:stay, args}

  @impl true
  @doc "`{:snapshot, png, report}`: keep it and show it."
  def handle_message({:snapshot, png, report}, _from, s) when is_binary(png) do
    Tartarus.Agent.store_put(:snapshot, png)
    Tartarus.Agent.store_put(:report, report)
    send(s.watcher, {:roadblock_snapshot, png, report})
    {:stay, s}
  end

  def handle_message(_other, _from, s), do: {:stay, s}
end
