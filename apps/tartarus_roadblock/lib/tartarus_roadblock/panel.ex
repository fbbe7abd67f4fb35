defmodule TartarusRoadblock.Panel do
  @moduledoc """
  The roadblock rescue on the web dashboard (`TartarusDashboard.Panel`): where Santa
  and the rescue stand, the latest events, the monitoring node's webcam snapshot once the
  administrator has it, and, while the run waits for the administrator, a button that
  releases the rescue agent (what `TartarusRoadblock.release_rescue/1` does from iex).

  `mix tartarus.roadblock --dashboard PORT` shows it. The scenario
  (`TartarusRoadblock.Scenario`) publishes its status into an ETS table after every step
  and when it starts or stops waiting for the administrator; the panel only reads that
  table, so the page never waits for the scenario's loop.
  """

  @behaviour TartarusDashboard.Panel

  @impl true
  @doc "Its name in URLs: `roadblock`."
  def name(_table), do: "roadblock"

  @impl true
  @doc "Rows: arena time, Santa, the block, the rescue agent and robot, the latest events."
  def render(table) do
    st = status(table)

    rows =
      [
        [
          "arena time",
          "#{st.t} s",
          if(st.waiting, do: "paused: waiting for the administrator", else: "")
        ],
        ["Santa", to_string(st.santa_phase), "x = #{st.santa_x} m"],
        ["block", block_state(st), st.block || ""],
        ["rescue agent", agent_state(st), "#{st.visited} hosts visited, #{st.hops} hops"],
        ["rescue robot", st.chosen || "not chosen yet", to_string(st.program_phase || "")]
      ] ++ Enum.map(st.events, fn e -> ["event", "#{e.t} s", "#{e.actor}: #{e.text}"] end)

    %{
      title: "Roadblock rescue (thesis §2.4)",
      text: text(st),
      columns: ["what", "state", "detail"],
      rows: rows,
      actions:
        if(st.waiting,
          do: [%{action: "release", label: "Release the rescue agent", params: %{}}],
          else: []
        ),
      image:
        st.snapshot &&
          %{type: "image/png", data: st.snapshot, alt: "the monitoring node's webcam snapshot"}
    }
  end

  @impl true
  @doc """
  `release`: releases the rescue agent while the run waits for the administrator
  (`{:ok, agent_id}`), else `{:error, :not_waiting}`.
  """
  def act(table, "release", _params) do
    if status(table).waiting,
      do: TartarusRoadblock.Control.release(),
      else: {:error, :not_waiting}
  end

  def act(_table, action, _params), do: {:error, {:unknown_action, action}}

  @doc """
  The status the scenario published in `table` (a map; defaults before the first step).
  """
  @spec status(:ets.tid() | atom()) :: map()
  def status(table) do
    case :ets.lookup(table, :status) do
      [{:status, st}] -> Map.merge(base_status(), st)
      [] -> base_status()
    end
  rescue
    # The run is over (its table went with it).
    ArgumentError -> %{base_status() | phase: :gone}
  end

  defp base_status,
    do: %{
      t: 0.0,
      phase: :driving,
      santa_phase: :driving,
      santa_x: 0.0,
      block: nil,
      chosen: nil,
      program_phase: nil,
      hops: 0,
      visited: 0,
      waiting: false,
      auto: true,
      events: [],
      snapshot: nil
    }

  defp block_state(%{block: nil}), do: "not there yet"
  defp block_state(%{phase: :done}), do: "off the path"
  defp block_state(_), do: "on the path"

  defp agent_state(%{waiting: true}), do: "not released: the administrator decides"
  defp agent_state(%{phase: p}) when p in [:driving, :admin], do: "not released"
  defp agent_state(%{phase: :rescue, chosen: nil}), do: "foraging for a rescue robot"
  defp agent_state(%{phase: :rescue}), do: "installed, guiding its robot"
  defp agent_state(%{phase: :done}), do: "done, back home"
  defp agent_state(_), do: ""

  defp text(%{phase: :gone}), do: "The run is over."

  defp text(%{waiting: true}),
    do:
      "Santa is blocked. The snapshot below is the monitoring node's webcam picture; release the rescue agent when you have looked at it."

  defp text(%{snapshot: nil}), do: "Santa drives from A to B; a block will appear on its path."

  defp text(_),
    do:
      "The rescue agent chose a robot by its capabilities and carries the rescue program as code."
end
