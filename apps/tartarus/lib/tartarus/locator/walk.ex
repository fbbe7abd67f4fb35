defmodule Tartarus.Locator.Walk do
  @moduledoc false
  # Walks over the overlay, for Tartarus.Locator (an agent known by its id alone) and
  # Tartarus.fleet/1.
  #
  # Where to start looking for agent `id`: a host of this node where it runs, arrives or left
  # a forwarding pointer; else the nodes of this node's hosts' overlay neighbours are asked,
  # and they ask theirs: one walk, depth first, at most @search_ttl overlay hops away, one
  # node at a time. The set of nodes asked travels with the walk and comes back with each
  # answer, so no node is asked twice however many paths lead to it (a 4x4 grid of 16 nodes:
  # at most 16 calls, where a visited set passed only downwards made 131 from a corner). The
  # walk has one time budget (@search_timeout in all): each node is given what is left, and
  # gives up when it is spent, so no part of a search outlives its caller by more than one
  # call. The overlay relays the search: no node connects to a node it is not linked with. A
  # node without hosts asks the nodes it is connected to. The fleet listing is the same walk
  # (walk/4), collecting each node's hosts instead of stopping at an agent.

  alias Tartarus.{Clock, Host, Ledger}

  # How deep (overlay hops between nodes along the walk) and how long (ms for the whole walk)
  # an agent known by its id alone is searched for. The walk asks each node once, so its
  # cost is bounded by the nodes reachable and the time, not by the paths between them; the
  # depth bound is generous because a depth-first walk may reach a near node by a long path.
  @search_ttl 32
  @search_timeout 2_000

  @doc false
  @spec search(binary(), non_neg_integer(), [node()]) :: {:ok, Host.t()} | :error
  def search(id, ttl \\ @search_ttl, visited \\ [node()]) do
    case walk({:agent, id}, ttl, visited, @search_timeout) do
      {:found, host} -> {:ok, host}
      {:walked, _asked, _seen} -> :error
    end
  end

  @doc false
  # The fleet as this node sees it (Tartarus.fleet/1): one walk over every node reachable
  # through the overlay, each giving its hosts, their residents and neighbours. A node
  # named as a neighbour that the walk did not reach (down, no answer in time) is listed
  # with `error: :not_reached`.
  @spec fleet(non_neg_integer()) :: [map()]
  def fleet(budget_ms) do
    {:walked, _asked, seen} = walk(:fleet, @search_ttl, [], budget_ms)
    reached = MapSet.new(seen, & &1.node)

    missed =
      for %{hosts: hosts} <- seen,
          h <- hosts,
          {_, n} <- h.neighbours,
          not MapSet.member?(reached, n),
          uniq: true,
          do: %{node: n, hosts: [], agents: 0, error: :not_reached}

    Enum.sort_by(seen ++ missed, & &1.node)
  end

  @doc false
  # One step of a walk over the overlay, on the node asked. What it looks for on each node,
  # `visit` (`{:agent, id}` or `:fleet`, see visit/2), answers `{:found, result}` (the walk
  # ends with it) or `{:seen, items}` (kept; the walk goes on). Returns `{:found, result}`,
  # or `{:walked, asked, items}` with every node the walk has asked so far (`visited` and
  # those asked from here) and the items seen on them.
  @spec walk({:agent, binary()} | :fleet, non_neg_integer(), [node()], non_neg_integer()) ::
          {:found, term()} | {:walked, [node()], [term()]}
  def walk(visit, ttl, visited, budget_ms) do
    deadline = Clock.monotonic_time(:millisecond) + budget_ms
    visited = if node() in visited, do: visited, else: [node() | visited]
    # This node's hosts, read once (a host that stopped meanwhile is left out).
    infos = for h <- Host.Starter.hosts(), {:ok, info} <- [Host.local(h)], do: info

    case visit(infos, visit) do
      {:found, _} = found ->
        found

      {:seen, items} when ttl > 0 ->
        Enum.reduce_while(next_nodes(infos), {:walked, visited, items}, fn
          n, {:walked, asked, items} = walked ->
            left = deadline - Clock.monotonic_time(:millisecond)

            cond do
              n in asked -> {:cont, walked}
              left <= 0 -> {:halt, walked}
              true -> ask(n, visit, ttl - 1, [n | asked], items, left)
            end
        end)

      {:seen, items} ->
        {:walked, visited, items}
    end
  end

  # The search's visit: this node's host where agent `id` runs, arrives or left a pointer.
  defp visit(infos, {:agent, id}) do
    case Tartarus.AgentTable.lookup(id) do
      {:ok, _pid, host_name} ->
        {:found, Host.address(host_name)}

      :error ->
        Enum.find_value(infos, {:seen, []}, fn info ->
          if Ledger.locate(info, id) != :not_found, do: {:found, info.ref}
        end)
    end
  end

  # The fleet's visit: this node's hosts, each with its resident count and neighbours.
  defp visit(infos, :fleet) do
    hosts =
      infos
      |> Enum.map(
        &%{host: &1.ref, agents: Ledger.counter(&1, :resident), neighbours: Ledger.neighbours(&1)}
      )
      |> Enum.sort_by(& &1.host)

    agents = hosts |> Enum.map(& &1.agents) |> Enum.sum()
    {:seen, [%{node: node(), hosts: hosts, agents: agents}]}
  end

  # (From a node that runs newer code.)
  defp visit(_infos, _other), do: {:seen, []}

  # The nodes of this node's hosts' neighbours; a node without hosts (a shell, a controller)
  # asks the nodes it is connected to.
  defp next_nodes([]), do: Node.list()

  defp next_nodes(infos),
    do: Enum.uniq(for info <- infos, {_, n} <- Ledger.neighbours(info), do: n)

  # {:halt, found} or {:cont, {:walked, asked, items}} for the walk's reduce; a node that
  # does not answer in time (or at all) counts as asked.
  defp ask(node, visit, ttl, asked, items, budget_ms) do
    case :erpc.call(node, __MODULE__, :walk, [visit, ttl, asked, budget_ms], budget_ms) do
      {:found, _} = found ->
        {:halt, found}

      {:walked, more, seen} when is_list(more) and is_list(seen) ->
        {:cont, {:walked, Enum.uniq(more ++ asked), items ++ seen}}

      _ ->
        {:cont, {:walked, asked, items}}
    end
  catch
    _, _ -> {:cont, {:walked, asked, items}}
  end
end
