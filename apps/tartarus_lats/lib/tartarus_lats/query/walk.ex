defmodule TartarusLats.Query.Walk do
  @moduledoc false
  # What every query agent does on a node: read the LATS entries of the host store,
  # remember where it has been and what it has heard of, search conscientiously, and
  # finish (one cloud contact from the node where the answer was found, then return).

  alias Tartarus.Agent, as: A

  @max_move_failures 3

  # The common part of a query agent's state.
  def new(args, type) when is_map(args) do
    %{
      type: type,
      tag: Map.fetch!(args, :tag),
      label: Map.get(args, :label),
      report: Map.get(args, :report, true),
      max_hops: Map.get(args, :max_hops, 500),
      started_us: System.monotonic_time(:microsecond),
      route: [],
      known: [],
      visited: [],
      failures: 0
    }
  end

  # Reads what this node offers and notes the visit. Returns {node, mv, neighbours, s}.
  def look(s) do
    node = A.store_get({:lats, :node})
    neighbours = A.store_get({:lats, :neighbours}, %{})
    mv = A.store_get({:lats, :mv})

    s = %{
      s
      | route: s.route ++ [node],
        visited: Enum.uniq([node | s.visited]),
        known: Enum.uniq(s.known ++ [node | Map.keys(neighbours)])
    }

    {node, mv, neighbours, s}
  end

  # No trace here: move on conscientiously, or give up once every node heard of was
  # visited (the network is exhausted) or the hop budget is spent.
  def search(s, give_up) do
    cond do
      Enum.all?(s.known, &(&1 in s.visited)) -> finish(give_up, s, false)
      A.hops() >= s.max_hops -> finish(give_up, s, false)
      true -> {:move, :conscientious, s}
    end
  end

  # Moves to the host of neighbour `node` (known from the host store).
  def go(neighbours, node, s, otherwise) do
    case Map.fetch(neighbours, node) do
      {:ok, host} -> {:move, host, s}
      :error -> otherwise.()
    end
  end

  def move_failed(s, retry) do
    s = %{s | failures: s.failures + 1}

    if s.failures > @max_move_failures,
      do: finish({:error, :unreachable}, s, false),
      else: retry.(s)
  end

  # Delivers the answer; `found` says whether relevant data was found here (then the
  # cloud is contacted, once, from this node).
  def finish(answer, s, found) do
    node = List.last(s.route)
    cloud = A.store_get({:lats, :cloud})

    if found and s.report and cloud != nil do
      Tartarus.post({TartarusLats.Cloud.agent_name(), cloud}, {
        :answer,
        %{
          query: s.label,
          type: s.type,
          tag: s.tag,
          time: A.store_get({:lats, :clock}, 0),
          node: node,
          answer: answer
        }
      })
    end

    result = %{
      type: s.type,
      tag: s.tag,
      label: s.label,
      answer: answer,
      hops: A.hops(),
      route: s.route,
      answered_at: node,
      cloud_contacts: if(found and s.report and cloud != nil, do: 1, else: 0),
      elapsed_us: System.monotonic_time(:microsecond) - s.started_us
    }

    {:return, result, s}
  end
end
