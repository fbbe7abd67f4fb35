defmodule TartarusRoadblock.Control do
  @moduledoc """
  The administrator's hand on a run that waits (`TartarusRoadblock.start/1`): releasing the
  rescue agent, for `TartarusRoadblock.release_rescue/1` in iex and the dashboard's
  button (`TartarusRoadblock.Panel`). It talks to the run's driver (the process registered
  as `TartarusRoadblock.Driver`) by message, and depends on nothing else but
  `Tartarus.Clock`.
  """

  alias Tartarus.Clock

  require Tartarus.Clock

  @doc """
  Releases the rescue agent of the run waiting for its administrator (see
  `TartarusRoadblock.release_rescue/1`). Returns `{:ok, agent_id}`, or
  `{:error, :no_run_waiting}`.
  """
  @spec release(keyword()) :: {:ok, String.t()} | {:error, :no_run_waiting}
  def release(opts \\ []) do
    case Process.whereis(TartarusRoadblock.Driver) do
      nil ->
        {:error, :no_run_waiting}

      pid ->
        ref = make_ref()
        send(pid, {:roadblock_release, self(), ref, opts})

        Clock.receive do
          {^ref, reply} -> reply
        after
          60_000 -> {:error, :no_run_waiting}
        end
    end
  end
end
