defmodule TartarusImmune.Panel do
  @moduledoc """
  Immune selection on the web dashboard (`TartarusDashboard.Panel`): the run going
  now (an experiment of `mix tartarus.select` makes one run per arm, data set and seed,
  each on its own network), its round, the live iPkts per solution, whether and when it
  converged, and for each host (the first #{64}) its pending problems and the iPkts in its
  interaction queue, by solution.

  `mix tartarus.select --dashboard PORT` shows it, beside the graph of the run's hosts
  (`TartarusEmu.Dashboard` given a function: the page follows the experiment from run to
  run). The run (`TartarusImmune.Experiment`, option `:panel`) publishes itself into an
  ETS table made by `new/0`; this panel reads the table and asks the hosts' `"immune"`
  agents, which only answer (the run does not depend on the page).
  """

  @behaviour TartarusDashboard.Panel

  import TartarusDashboard.Panel, only: [lookup: 2]

  @rows_max 64

  @doc "A table for runs to publish themselves into (public; owned by the caller)."
  @spec new() :: :ets.tid()
  def new, do: :ets.new(:tartarus_immune_panel, [:public, :set])

  @doc "Forgets the run that ended (its network is going); nothing without a table."
  @spec clear(:ets.tid() | nil) :: :ok
  def clear(table) do
    TartarusDashboard.Panel.publish(table, fn t ->
      :ets.delete(t, :run)
      :ets.delete(t, :round)
    end)
  end

  @doc """
  The network of the run going now, or nil.

      iex> TartarusImmune.Panel.network(TartarusImmune.Panel.new())
      nil
  """
  @spec network(:ets.tid()) :: TartarusEmu.Network.t() | nil
  def network(table) do
    case lookup(table, :run) do
      [{:run, r}] -> r.net
      _ -> nil
    end
  end

  @impl true
  @doc "Its name in URLs: `immune`."
  def name(_table), do: "immune"

  @impl true
  @doc "A row per host (the first #{@rows_max}), and a line on the run."
  def render(table) do
    case lookup(table, :run) do
      [{:run, r}] ->
        run_view(table, r)

      :gone ->
        %{title: title(nil), text: "The experiment is over.", columns: columns(), rows: []}

      _ ->
        %{title: title(nil), text: "Between two runs.", columns: columns(), rows: []}
    end
  end

  @impl true
  @doc "No actions: the experiment runs on its own."
  def act(_table, action, _params), do: {:error, {:unknown_action, action}}

  defp run_view(table, r) do
    {round, pop, converged} =
      case lookup(table, :round) do
        [{:round, k, pop, conv}] -> {k, pop, conv}
        _ -> {0, %{}, nil}
      end

    nodes = r.net.topology.nodes

    rows =
      nodes
      |> Enum.take(@rows_max)
      |> Enum.map(fn node ->
        host = TartarusEmu.Network.host(r.net, node)

        with {:ok, queue} when is_list(queue) <-
               Tartarus.request({"immune", host}, :queue, 2_000),
             {:ok, pending} <- Tartarus.request({"immune", host}, :pending, 2_000) do
          [to_string(node), pending, length(queue), solutions(queue, r.domain)]
        else
          other -> [to_string(node), nil, nil, "unreachable: #{inspect(other)}"]
        end
      end)

    %{
      title: title(r.label),
      text:
        "Round #{round}, data set #{r.set}: live iPkts #{counts(pop)}; " <>
          converged_text(converged) <>
          if(length(nodes) > @rows_max, do: " Showing the first #{@rows_max} hosts.", else: ""),
      columns: columns(),
      rows: rows,
      actions: []
    }
  end

  defp columns, do: ["host", "problems pending", "iPkts queued", "iPkts by solution"]

  defp title(nil), do: "Immune selection (thesis ch. 6)"
  defp title(label), do: "Immune selection (thesis ch. 6): #{label}"

  defp solutions(queue, domain) do
    queue
    |> Enum.frequencies_by(& &1.sol)
    |> Enum.map(fn {sol, n} -> {domain.solution_name(sol), n} end)
    |> counts()
  end

  defp counts(pop) when map_size(pop) == 0, do: "none"
  defp counts(pop) when pop == [], do: "none"

  defp counts(pop) do
    pop
    |> Enum.sort_by(fn {name, n} -> {-n, to_string(name)} end)
    |> Enum.map_join(", ", fn {name, n} -> "#{name} #{n}" end)
  end

  defp converged_text(nil), do: "not converged yet."

  defp converged_text({step, sol}), do: "converged on #{sol} at round #{step}."
end
