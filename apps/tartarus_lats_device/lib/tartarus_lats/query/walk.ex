defmodule TartarusLats.Query.Walk do
  @moduledoc false
  # What every query agent does on a node: read the LATS entries of the host store,
  # remember where it has been and what it has heard of, search conscientiously, and
  # finish. Cloud contacts (thesis §3.4, scenario 2): by default (`cloud: :per_node`) the
  # agent contacts the cloud from every node where it finds data of its tag (a confirmed
  # stay in the node's motion vectors), once per node; with `cloud: :per_query`, once, from
  # the node where the answer was found. The result says how many it made and, for both
  # rules, how many it would have made (`data_nodes`, `found`).

  alias Tartarus.Agent, as: A
  alias Tartarus.Clock

  @max_move_failures 3

  # How old the evidence of an answer that a person is between zones (left a node, not
  # found at the next) may be before the answer is stale: a hand-over is confirmed within
  # the motion vectors' handshake timeout (15 s by default), so past twice that the person
  # is not in transit any more, only lost track of.
  @stale_after 30

  @doc false
  def stale_after, do: @stale_after

  # The common part of a query agent's state.
  def new(args, type) when is_map(args) do
    %{
      type: type,
      tag: Map.fetch!(args, :tag),
      label: Map.get(args, :label),
      report: Map.get(args, :report, true),
      cloud: Map.get(args, :cloud, :per_node),
      data_nodes: [],
      unreachable: [],
      max_hops: Map.get(args, :max_hops, 500),
      started_us: Clock.monotonic_time(:microsecond),
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

    {node, mv, neighbours, found_data(s, node, mv)}
  end

  # First visit of a node holding data of the tag: noted, and under the per-node rule the
  # cloud is told what was found here.
  defp found_data(s, node, mv) do
    stay = TartarusLats.Query.latest(mv, s.tag)

    if stay == nil or node in s.data_nodes do
      s
    else
      if s.cloud == :per_node, do: contact_cloud(s, node, {:found_here, stay})
      %{s | data_nodes: s.data_nodes ++ [node]}
    end
  end

  defp contact_cloud(s, node, what) do
    cloud = A.store_get({:lats, :cloud})

    if s.report and cloud != nil do
      Tartarus.post({TartarusLats.Cloud.agent_name(), cloud}, {
        :answer,
        %{
          query: s.label,
          type: s.type,
          tag: s.tag,
          time: A.store_get({:lats, :clock}, 0),
          node: node,
          answer: what
        }
      })

      1
    else
      0
    end
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

  def move_failed(s, dest, retry) do
    s = %{unreachable(s, dest) | failures: s.failures + 1}

    if s.failures > @max_move_failures,
      do: finish({:error, :unreachable}, s, false),
      else: retry.(s)
  end

  # Notes that the node of host `dest` could not be reached (the answer is then not complete).
  def unreachable(s, dest), do: %{s | unreachable: Enum.uniq(s.unreachable ++ [node_of(dest)])}

  # The building node a destination host stands for (the neighbours map names them).
  defp node_of(dest) do
    neighbours = A.store_get({:lats, :neighbours}, %{})

    case Enum.find(neighbours, fn {_node, host} -> host == dest end) do
      {node, _} -> node
      nil -> dest
    end
  end

  # What an answer rests on, on this node's clock: `{evidence_at, freshness}`. Present
  # somewhere (Where is: in a zone; Trace: present) is evidence of now; an exit from the
  # building is the exit's time and stays current (nothing later was seen); a departure not
  # followed to a next zone (in transit, a broken trace) is the departure's time, stale once
  # older than @stale_after. No answer, no evidence.
  defp evidence(answer, s, clock) do
    here = TartarusLats.Query.latest(A.store_get({:lats, :mv}), s.tag)

    case answer do
      {:in_zone, _} -> {clock, :current}
      :left_building -> {left_at(here, clock), :current}
      {:in_transit, _} -> aged(left_at(here, clock), clock)
      {:ok, %{status: :present}} -> {clock, :current}
      {:ok, %{status: :exited, path: path}} -> {left_at(List.last(path), clock), :current}
      {:ok, %{path: [_ | _] = path}} -> aged(left_at(List.last(path), clock), clock)
      _ -> {nil, :none}
    end
  end

  # Complete: nothing the walk needed was out of reach, every break of the chain it met
  # was bridged from the node itself or a neighbour, or over two rings through the one
  # zone between (`TartarusLats.Query.Bridge`), and a Trace walked back to the building's entry (status present or
  # exited, not broken or in transit).
  defp complete?(answer, s) do
    s.unreachable == [] and
      Enum.all?(Map.get(s, :breaks, []), &bridged?/1) and
      case answer do
        {:ok, %{status: status, entry: :infinity}} -> status in [:present, :exited]
        {:ok, _} -> false
        _ -> true
      end
  end

  # A break of the chain bridged so that no zone is unknown (see complete?/2).
  def bridged?(%{bridged_to: to, ring: ring} = b),
    do: to != nil and (ring <= 1 or Map.get(b, :through) != nil)

  defp left_at(%{left_at: t}, _clock) when is_number(t), do: t
  defp left_at(_stay, clock), do: clock

  defp aged(t, clock), do: {t, if(clock - t > @stale_after, do: :stale, else: :current)}

  # Delivers the answer; `found` says whether relevant data was found here (then the
  # cloud is contacted, once, from this node).
  def finish(answer, s, found) do
    node = List.last(s.route)
    cloud = A.store_get({:lats, :cloud})
    # Per-node rule: a node with data was contacted from on arrival; the answer's node, if
    # it had no data (e.g. Where am I next to the user), is contacted from now. Per-query
    # rule: one contact, from here, if the answer was found.
    s =
      cond do
        found and s.cloud == :per_node and node not in s.data_nodes ->
          contact_cloud(s, node, answer)
          %{s | data_nodes: s.data_nodes ++ [node]}

        found and s.cloud == :per_query ->
          contact_cloud(s, node, answer)
          s

        true ->
          s
      end

    contacts =
      cond do
        not s.report or cloud == nil -> 0
        s.cloud == :per_node -> length(s.data_nodes)
        found -> 1
        true -> 0
      end

    clock = A.store_get({:lats, :clock}, 0)
    {evidence_at, freshness} = evidence(answer, s, clock)

    result = %{
      type: s.type,
      tag: s.tag,
      label: s.label,
      answer: answer,
      hops: A.hops(),
      route: s.route,
      answered_at: node,
      cloud_contacts: contacts,
      # How fresh and complete the answer is (see evidence/3).
      asked_at: clock,
      evidence_at: evidence_at,
      freshness: freshness,
      unreachable: s.unreachable,
      # Where the chain of motion vectors broke, and how each break was bridged.
      breaks: Map.get(s, :breaks, []),
      complete: complete?(answer, s),
      # What each rule costs for this query, whichever was applied.
      per_node_contacts: length(Enum.uniq(s.data_nodes ++ if(found, do: [node], else: []))),
      per_query_contacts: if(found, do: 1, else: 0),
      elapsed_us: Clock.monotonic_time(:microsecond) - s.started_us
    }

    {:return, result, s}
  end
end
