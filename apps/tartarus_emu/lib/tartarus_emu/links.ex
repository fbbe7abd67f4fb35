defmodule TartarusEmu.Links do
  @moduledoc """
  The emulator's transport (`Tartarus.Transport`): the latency and loss of emulated links,
  read from the link properties the emulator gives `Tartarus.connect/3`.

    * A hand-off over a link with `latency_ms: L` waits `3 * L` ms of the clock
      (`Tartarus.Clock.sleep/1`) in the source before it sends `prepare` (its three
      messages: prepare, prepared, commit; the modules' round trip of a first crossing is
      not charged); with `loss: p` it fails with `:link_loss` with probability `p`, drawn
      from the agent's own random stream (runs are reproducible).
    * Every other message between two hosts (an agent's message to an agent on another
      host, a signal relay, a broadcast) costs its **route**: the sum of the latencies of
      the links on the cheapest path between them over the live overlay links of this
      node's hosts (one link: `L`; a host and itself: 0). An agent's message waits it each
      way (the acknowledgement or the reply comes back the same way).
    * Two hosts with no route between them on this node (a partition, or a host of another
      BEAM node that is not a neighbour) cost nothing beyond the real network.

  `TartarusEmu.Network` installs it (`install/1`) on the nodes of the hosts it links with a
  latency or a loss; install it yourself to emulate links made with `Tartarus.connect/3`
  directly.
  """

  @behaviour Tartarus.Transport

  @doc "Installs this transport on `nodes` (default: this node)."
  @spec install([node()]) :: :ok
  def install(nodes \\ [node()]) do
    Enum.each(Enum.uniq(nodes), fn
      n when n == node() -> Tartarus.Transport.install(__MODULE__)
      n -> :ok = :erpc.call(n, Tartarus.Transport, :install, [__MODULE__], 15_000)
    end)
  end

  @doc "True for link properties this transport acts on (a latency or a loss)."
  @spec emulated?(map() | keyword()) :: boolean()
  def emulated?(props) do
    props = Map.new(props)
    Map.get(props, :latency_ms, 0) > 0 or Map.get(props, :loss, 0) > 0
  end

  @impl true
  def hand_off(host, dest, rng) do
    case Tartarus.Transport.link(host, dest) do
      %{} = props ->
        latency = Map.get(props, :latency_ms, 0)
        if latency > 0, do: Tartarus.Clock.sleep(3 * latency)
        loss = Map.get(props, :loss, 0)

        if loss > 0 do
          {x, state} = :rand.uniform_s(:rand.seed_s(rng))
          rng = :rand.export_seed_s(state)
          if x < loss, do: {:error, :link_loss, rng}, else: {:ok, rng}
        else
          {:ok, rng}
        end

      nil ->
        {:ok, rng}
    end
  end

  @impl true
  def message_delay(%{ref: host}, host), do: 0

  def message_delay(from, host) do
    case Tartarus.Transport.link(from, host) do
      %{latency_ms: ms} -> ms
      %{} -> 0
      nil -> route(from.ref, host)
    end
  end

  @doc """
  The cost in ms of the cheapest route from host `from` to host `to` over the live links of
  this node's hosts (Dijkstra on the links' `:latency_ms`), or 0 when there is none.
  """
  @spec route(Tartarus.host(), Tartarus.host()) :: non_neg_integer()
  def route(from, to) when from == to, do: 0

  def route(from, to), do: dijkstra(:gb_sets.singleton({0, from}), to, %{from => 0})

  defp dijkstra(frontier, to, best) do
    if :gb_sets.is_empty(frontier) do
      0
    else
      {{d, host}, frontier} = :gb_sets.take_smallest(frontier)

      cond do
        host == to ->
          d

        d > Map.get(best, host, d) ->
          dijkstra(frontier, to, best)

        true ->
          {frontier, best} =
            Enum.reduce(Tartarus.Transport.links_of(host), {frontier, best}, fn {n, props},
                                                                                {f, b} ->
              nd = d + Map.get(props, :latency_ms, 0)

              if nd < Map.get(b, n, nd + 1),
                do: {:gb_sets.add({nd, n}, f), Map.put(b, n, nd)},
                else: {f, b}
            end)

          dijkstra(frontier, to, best)
      end
    end
  end
end
