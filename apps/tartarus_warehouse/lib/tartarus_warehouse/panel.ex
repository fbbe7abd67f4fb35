defmodule TartarusWarehouse.Panel do
  @moduledoc """
  The warehouse on the web dashboard (`TartarusDashboard.Panel`): the floor running
  now (an experiment starts one per point and per design), its jobs done, and for each
  robot its state (thesis §4.3), the tasks it runs, the job and the task agent it serves,
  the tasks it ran so far; and the mutual-exclusion violations (Eq. 4.1) in what the
  robots ran so far, checked live on floors of up to #{64} robots.

  `mix tartarus.warehouse --dashboard PORT` shows it, beside the graph of the floor's
  hosts (`TartarusEmu.Dashboard` given a function: the page follows the experiment from
  floor to floor). The floor (`TartarusWarehouse.Floor`, option `:status`) publishes
  itself into an ETS table made by `new/0`; this panel reads the table and asks the robot
  plugins, so the page never waits for the experiment.
  """

  @behaviour TartarusDashboard.Panel

  import TartarusDashboard.Panel, only: [lookup: 2]

  alias TartarusWarehouse.Checker

  @live_max 64

  @doc "A table for a floor to publish itself into (public; owned by the caller)."
  @spec new() :: :ets.tid()
  def new, do: :ets.new(:tartarus_warehouse_panel, [:public, :set])

  @doc """
  Notes which experiment point runs now (`experiment`, e.g. `:scaling`, and its point,
  e.g. 20 tasks per job), for the panel's title line.
  """
  @spec point(:ets.tid(), atom(), term()) :: :ok
  def point(table, experiment, point) do
    :ets.insert(table, {:point, experiment, point})
    :ok
  end

  @doc """
  The network of the floor running now, or nil (between two floors, or after the run).

      iex> t = TartarusWarehouse.Panel.new()
      iex> TartarusWarehouse.Panel.network(t)
      nil
  """
  @spec network(:ets.tid()) :: TartarusEmu.Network.t() | nil
  def network(table) do
    case lookup(table, :floor) do
      [{:floor, f}] -> f.net
      _ -> nil
    end
  end

  @impl true
  @doc "Its name in URLs: `warehouse`."
  def name(_table), do: "warehouse"

  @impl true
  @doc "A row per robot (the first #{@live_max}), and a line on the floor and its jobs."
  def render(table) do
    case lookup(table, :floor) do
      [{:floor, f}] -> floor_view(table, f)
      _ -> %{title: title(table), text: idle_text(table), columns: columns(), rows: []}
    end
  end

  @impl true
  @doc "No actions: the experiment runs on its own."
  def act(_table, action, _params), do: {:error, {:unknown_action, action}}

  defp floor_view(table, f) do
    {total, done} =
      case lookup(table, :jobs) do
        [{:jobs, total, done}] -> {total, done}
        _ -> {0, 0}
      end

    robots = Enum.sort_by(f.robot_hosts, fn {"r" <> i, _} -> String.to_integer(i) end)
    shown = Enum.take(robots, @live_max)

    rows =
      Enum.map(shown, fn {name, host} ->
        case Tartarus.read_plugin(host, :robot, :state) do
          {:ok, st} ->
            [
              name,
              state_text(st),
              if(st.running, do: Enum.join(st.running, ", "), else: ""),
              job_text(st.job),
              st.busy,
              st.executions
            ]

          {:error, reason} ->
            [name, "unreachable: #{inspect(reason)}", "", "", nil, nil]
        end
      end)

    secs = (Tartarus.Clock.system_time(:microsecond) - f.t0_us) / 1_000_000

    %{
      title: title(table),
      text:
        "#{design_text(f)} on #{robots_text(length(robots))}: #{done} of #{total} jobs done after " <>
          "#{:erlang.float_to_binary(secs, decimals: 1)} s. " <>
          violations_text(robots) <>
          if(length(robots) > @live_max,
            do: " Showing the first #{@live_max} robots.",
            else: ""
          ),
      columns: columns(),
      rows: rows,
      actions: []
    }
  end

  defp columns, do: ["robot", "state", "running", "job", "task agent", "tasks run"]

  defp title(table) do
    case lookup(table, :point) do
      [{:point, experiment, point}] ->
        "Warehouse (thesis ch. 4): #{experiment}, #{point_text(experiment, point)}"

      _ ->
        "Warehouse (thesis ch. 4)"
    end
  end

  defp point_text(:robots, k), do: robots_text(k)
  defp point_text(:scaling, n), do: "#{n} tasks per job"
  defp point_text(_, point), do: "run #{point}"

  defp robots_text(1), do: "1 robot"
  defp robots_text(k), do: "#{k} robots"

  defp idle_text(table) do
    case lookup(table, :point) do
      :gone -> "The run is over."
      [] -> "No floor yet."
      _ -> "Between two floors."
    end
  end

  defp design_text(%{design: :central}), do: "The central server"
  defp design_text(%{guide: true}), do: "Task agents guided by signal fields"
  defp design_text(_), do: "Task agents (the thesis's search)"

  defp state_text(%{off: true}), do: "out of service"
  defp state_text(%{retiring: true} = st), do: "retiring (#{state_name(st.state)})"
  defp state_text(st), do: state_name(st.state)

  defp state_name(:free), do: "S1* (free)"
  defp state_name({:inserted, task, _next}), do: "waiting for inserted #{task}"

  defp state_name({job, seq, index}),
    do: "booked: job #{inspect(job)}, sequence #{seq}, block #{index}"

  defp state_name(other), do: inspect(other)

  defp job_text({job, seq}), do: "#{inspect(job)}, sequence #{seq}"
  defp job_text(_), do: ""

  # Eq. 4.1 over what the robots ran so far (small floors only: it reads every history).
  defp violations_text(robots) when length(robots) > @live_max,
    do: "Mutual exclusion is checked after the run on floors this large."

  defp violations_text(robots) do
    case length(Checker.violations(TartarusWarehouse.Robot.history(robots))) do
      0 -> "No two robots have held one resource at once so far."
      n -> "MUTUAL-EXCLUSION VIOLATIONS so far: #{n}."
    end
  end
end
