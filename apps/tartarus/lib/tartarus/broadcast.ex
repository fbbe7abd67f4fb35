defmodule Tartarus.Broadcast do
  @moduledoc """
  Neighbour broadcast: a host sends one message to every neighbour host.

  `Tartarus.broadcast(host, message)` (from outside) or `Tartarus.Agent.broadcast(message)`
  (from an agent, for the host it is on) sends `message` to each current neighbour of the
  host: one message per neighbour over the overlay link, handled by the node-level process
  `Tartarus.Overlay` of the neighbour's node, so it works across BEAM nodes.

  ## Who receives

  On each neighbour host, every process **subscribed** to that host's broadcasts receives
  `{:tartarus_broadcast, from_host, message}`:

    * an agent subscribes with `Tartarus.Agent.subscribe_broadcasts/0`; broadcasts then
      arrive in its `c:Tartarus.Agent.handle_info/2`. The subscription ends when the agent
      leaves the host (like plugin subscriptions): subscribe again on arrival;
    * any other process subscribes with `subscribe/1` (e.g. a static service, or an
      experiment driver that watches a host); it ends with `unsubscribe/1` or when the
      process exits.

  Agents that did not subscribe receive nothing: a broadcast never disturbs code that does
  not expect it, and a host with many residents does not wake them all.

  Delivery is best effort, like a radio broadcast: nothing is retried, a neighbour host
  that stopped (or a node that is unreachable) just misses the message, and a subscriber
  that moves away meanwhile may miss it.

  ## Counting

  A broadcast is counted for the sending host exactly like migrations: the counters
  `:broadcasts` (+1), `:broadcast_messages` (+1 per neighbour) and `:broadcast_bytes` (the
  `:erlang.external_size/1` of each message that crosses a link: the message with its
  addressing), and one event of type `:broadcast` with `:to` (the neighbours), `:messages`
  and `:bytes` (total). Each receiving host counts `:broadcasts_received` (event
  `:broadcast_received` with `:from` and `:bytes`). So the cost of sharing by broadcast
  compares directly with sharing by agents (`:departures`, `:bytes`).

  ## Example

      iex> {:ok, _} = Tartarus.start_host(:bc_a)
      iex> {:ok, _} = Tartarus.start_host(:bc_b, neighbours: [:bc_a])
      iex> Tartarus.Broadcast.subscribe(:bc_b)
      :ok
      iex> Tartarus.broadcast(:bc_a, {:antibody, [0.1, 0.7]})
      {:ok, 1}
      iex> receive do
      ...>   {:tartarus_broadcast, {:bc_a, _}, message} -> message
      ...> end
      {:antibody, [0.1, 0.7]}
      iex> Tartarus.status(:bc_a).counts.broadcast_messages
      1
      iex> Tartarus.stop_host(:bc_a)
      :ok
      iex> Tartarus.stop_host(:bc_b)
      :ok
  """

  alias Tartarus.{Events, Host, Ledger}

  @doc """
  Sends `message` to every neighbour of `host`. Returns `{:ok, n}` with the number of
  neighbours it was sent to, or `{:error, {:unknown_host, host}}`. `message` must be plain
  data (no funs or ports: it may cross nodes).
  """
  @spec broadcast(Tartarus.host_ref(), term()) :: {:ok, non_neg_integer()} | {:error, term()}
  def broadcast(host, message) do
    with :ok <- portable(message),
         do: Host.on_node(host, __MODULE__, :local_broadcast, [message])
  end

  @doc false
  # On the host's node (see Tartarus.Host.on_node/4).
  def local_broadcast(host, message) do
    with {:ok, info} <- Host.local(host), do: {:ok, send_from(info, message)}
  end

  defp portable(message) do
    case Tartarus.Envelope.portable?(message) do
      :ok -> :ok
      {:error, reason} -> {:error, reason}
    end
  end

  @doc false
  # Sends from a host on this node (`info` is its info map): the calling process (an agent,
  # or the caller of broadcast/2) sends the messages itself. Returns how many it sent.
  @spec send_from(map(), term()) :: non_neg_integer()
  def send_from(info, message) do
    targets = Ledger.neighbours(info)

    bytes =
      Enum.reduce(targets, 0, fn to, acc ->
        msg = {:"$tartarus_broadcast", to, info.ref, message}
        Host.overlay_send(to, msg, Tartarus.Transport.delay(info, to))
        acc + :erlang.external_size(msg)
      end)

    n = length(targets)

    Events.emit(
      info,
      %{type: :broadcast, host: info.ref, to: targets, messages: n, bytes: bytes},
      broadcasts: 1,
      broadcast_messages: n,
      broadcast_bytes: bytes
    )

    n
  end

  @doc """
  Subscribes the calling process (or `pid`) to the broadcasts that reach `host`: it
  receives `{:tartarus_broadcast, from_host, message}` for each. Subscribing twice is the
  same as once.
  """
  @spec subscribe(Tartarus.host_ref(), pid()) :: :ok | {:error, term()}
  def subscribe(host, pid \\ self()), do: overlay_call(host, {:subscribe, pid})

  @doc "Ends a subscription made with `subscribe/2`."
  @spec unsubscribe(Tartarus.host_ref(), pid()) :: :ok | {:error, term()}
  def unsubscribe(host, pid \\ self()), do: overlay_call(host, {:unsubscribe, pid})

  @doc "The processes subscribed to `host`'s broadcasts (a host on this node)."
  @spec subscribers(Tartarus.host_ref()) :: [pid()]
  def subscribers(host) do
    {name, _} = Host.address(host)
    for {_, pid} <- :ets.lookup(:tartarus_broadcast_subscribers, name), do: pid
  end

  defp overlay_call(host, request), do: Host.overlay_call(host, request)

  @doc false
  # In the overlay process: a broadcast arrived for host `info` from `from`.
  def deliver(info, from, message, bytes) do
    {name, _} = info.ref

    Events.emit(
      info,
      %{type: :broadcast_received, host: info.ref, from: from, bytes: bytes},
      broadcasts_received: 1
    )

    for {_, pid} <- :ets.lookup(:tartarus_broadcast_subscribers, name) do
      send(pid, {:tartarus_broadcast, from, message})
    end

    :ok
  end
end
