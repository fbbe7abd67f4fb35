defmodule TartarusLats.DashboardPanel do
  @moduledoc """
  LATS on the web dashboard (`TartarusDashboard.Panel`): where each tag bearer is, as
  the building's receivers hear it now (the node whose receiver heard the tag loudest in
  its last scan), and the query agents out in the building (where each is now and how many
  hops it made; the page's event list, filtered by an agent's id, shows its path).

  `mix tartarus.lats --dashboard PORT` shows it (`TartarusLats.Experiment.panels/1`). It
  reads only through the platform: `Tartarus.read_plugin/3` on each node's `:beacon`
  receiver and `Tartarus.agents/1` on each host.
  """

  @behaviour TartarusDashboard.Panel

  alias TartarusEmu.Network

  @typedoc "What the panel reads: the network and the bearers' names by tag."
  @type arg :: %{net: Network.t(), bearers: %{term() => atom() | String.t()}}

  @impl true
  @doc "Two panels' worth in one: its name in URLs is `lats`."
  def name(_arg), do: "lats"

  @impl true
  @doc "Rows: one per bearer heard (the loudest node), then one per query agent out."
  def render(%{net: net, bearers: bearers}) do
    nodes = Enum.filter(net.topology.nodes, &Network.up?(net, &1))

    loudest =
      Enum.reduce(nodes, %{}, fn n, acc ->
        case Tartarus.read_plugin(Network.host(net, n), :beacon, :last) do
          {:ok, {t, readings}} when is_map(readings) ->
            Enum.reduce(readings, acc, fn {tag, rssi}, acc ->
              case acc do
                %{^tag => {_, best, _}} when best >= rssi -> acc
                _ -> Map.put(acc, tag, {n, rssi, t})
              end
            end)

          _ ->
            acc
        end
      end)

    bearer_rows =
      for {tag, {n, rssi, t}} <-
            Enum.sort_by(loudest, fn {tag, _} -> inspect(Map.get(bearers, tag, tag)) end) do
        [
          "bearer",
          to_string(Map.get(bearers, tag, "unknown tag")),
          to_string(n),
          "#{rssi} dBm at #{t} s"
        ]
      end

    query_rows =
      for n <- nodes,
          a <- agents(Network.host(net, n)),
          query?(a.module) do
        hops =
          case Tartarus.agent_info({a.id, Network.host(net, n)}) do
            {:ok, info} -> "#{Map.get(info, :hops, 0)} hops"
            _ -> ""
          end

        ["query " <> a.id, inspect(a.module), to_string(n), hops]
      end

    %{
      title: "LATS: tag bearers and query agents",
      text:
        "A bearer is where its tag was heard loudest in the last scan; filter the events by a query's id to see its path.",
      columns: ["what", "who", "node", "detail"],
      rows: bearer_rows ++ query_rows,
      actions: []
    }
  end

  @impl true
  @doc "No actions (queries are released by the experiment's schedule)."
  def act(_arg, action, _params), do: {:error, {:unknown_action, action}}

  defp agents(host) do
    case Tartarus.agents(host) do
      list when is_list(list) -> list
      _ -> []
    end
  end

  defp query?(module), do: String.starts_with?(inspect(module), "TartarusLats.Query.")
end
