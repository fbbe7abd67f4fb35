defmodule TartarusDashboard.Processes do
  @moduledoc """
  A node's top processes, as Phoenix LiveDashboard's and observer's process lists show them:
  the `limit` processes using the most memory, reductions or mailbox, each named by what it
  is (an agent by its id, name and module; else its registered name or initial call) with
  its current function.

  Read on the node itself (the dashboard asks another node along the fleet's path,
  `TartarusDashboard.Fleet.forward/2`) and only when asked (the page's Processes tab).
  One reading asks every process of the node for three numbers (at most `@max_scan` of
  them, the first in `Process.list/0`'s order beyond that), then names only the top ones.
  """

  @max_scan 200_000
  @sorts %{"memory" => :memory, "reductions" => :reductions, "mailbox" => :message_queue_len}

  @doc "The sort keys `top/2` takes."
  @spec sorts() :: [String.t()]
  def sorts, do: Map.keys(@sorts) |> Enum.sort()

  @doc """
  This node's top `limit` processes by `sort` (`"memory"`, `"reductions"` or `"mailbox"`):
  `%{node, total, scanned, sort, processes: [%{pid, name, kind, memory, reductions,
  mailbox, current}]}` (`kind`: `"agent"` or `"process"`; memory in bytes, reductions since
  the process started).

      iex> %{processes: [p | _]} = TartarusDashboard.Processes.top("memory", 3)
      iex> Map.keys(p) |> Enum.sort()
      [:current, :kind, :mailbox, :memory, :name, :pid, :reductions]
  """
  @spec top(String.t(), pos_integer()) :: map()
  def top(sort, limit) when is_map_key(@sorts, sort) and is_integer(limit) and limit > 0 do
    key = Map.fetch!(@sorts, sort)
    pids = Process.list()
    scan = Enum.take(pids, @max_scan)

    rows =
      for pid <- scan,
          info = Process.info(pid, [:memory, :reductions, :message_queue_len]),
          info != nil,
          do: {pid, Map.new(info)}

    agents = Map.new(Tartarus.agents(), &{&1.pid, &1})

    top =
      rows
      |> Enum.sort_by(fn {_pid, i} -> -i[key] end)
      |> Enum.take(limit)
      |> Enum.map(fn {pid, i} -> row(pid, i, agents) end)

    %{
      node: to_string(node()),
      total: length(pids),
      scanned: length(scan),
      sort: sort,
      processes: top
    }
  end

  defp row(pid, i, agents) do
    {kind, name} =
      case agents do
        %{^pid => a} ->
          {"agent", "#{a.id} #{if a.name, do: inspect(a.name) <> " "}(#{inspect(a.module)})"}

        _ ->
          {"process", process_name(pid)}
      end

    %{
      pid: inspect(pid),
      name: name,
      kind: kind,
      memory: i.memory,
      reductions: i.reductions,
      mailbox: i.message_queue_len,
      current: current(pid)
    }
  end

  defp process_name(pid) do
    case Process.info(pid, :registered_name) do
      {:registered_name, name} when is_atom(name) and name != [] ->
        inspect(name)

      _ ->
        case :proc_lib.translate_initial_call(pid) do
          {m, f, a} -> Exception.format_mfa(m, f, a)
          _ -> ""
        end
    end
  end

  defp current(pid) do
    case Process.info(pid, :current_function) do
      {:current_function, {m, f, a}} -> Exception.format_mfa(m, f, a)
      _ -> ""
    end
  end
end
