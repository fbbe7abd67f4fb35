defmodule Tartarus.Host do
  @moduledoc """
  Hosts: where agents live and what they migrate between (DESIGN §4).

  A host is addressed by `{name, node}`; on its own node a bare `name` is enough. Names are
  atoms or strings. A host has:

    * an **overlay neighbour set**, with optional per-link properties (`:latency_ms`,
      `:loss`) that emulations use; agents usually move to neighbours;
    * a **ledger**: resident agents, arrival and departure counts, recent hop times, visit
      count, forwarding pointers for departed agents, and migration decisions;
    * a **store**: a small key-value table that agents on the host read and write
      (`Tartarus.Agent.store_get/2`, `store_put/2`);
    * **plugins**: device drivers reachable by the agents on the host (`Tartarus.Plugin`).

  Users go through the `Tartarus` facade; this module holds the few helpers the other
  platform modules share (addresses, finding a host, calling its server). A host's options
  are described in `Tartarus.start_host/2` and validated by `Tartarus.Options.Platform`.
  """

  @typedoc "A host's name: an atom or a string."
  @type name :: atom() | String.t()

  @typedoc "A host's address."
  @type t :: {name(), node()}

  @doc """
  True if `term` is a host name or address.

      iex> Tartarus.Host.address?(:a)
      true
      iex> Tartarus.Host.address?({"lab-3", :"n1@pi"})
      true
      iex> Tartarus.Host.address?(3)
      false
  """
  @spec address?(term()) :: boolean()
  def address?({name, node}), do: name?(name) and is_atom(node) and node != nil
  def address?(name), do: name?(name)

  defp name?(name) when is_boolean(name) or is_nil(name), do: false
  defp name?(name), do: is_atom(name) or (is_binary(name) and byte_size(name) in 1..255)

  @doc """
  The full address of a host: a bare name means a host on this node.

      iex> Tartarus.Host.address(:a)
      {:a, node()}
  """
  @spec address(name() | t()) :: t()
  def address({_name, _node} = host), do: host
  def address(name), do: {name, node()}

  @doc false
  # The registered name of one process of a host's tree on this node (`:host_sup`, `:host`,
  # `:agents`, `:plugins`), in `Tartarus.HostRegistry`. Here rather than in
  # `Tartarus.Host.Supervisor`, so the host's server can name its siblings without depending
  # on the supervisor that starts it.
  @spec via(atom(), name()) :: {:via, Registry, {Tartarus.HostRegistry, {atom(), name()}}}
  def via(kind, name), do: {:via, Registry, {Tartarus.HostRegistry, {kind, name}}}

  @doc """
  The address a host name means to a host whose neighbours are `neighbours` (full
  addresses): the neighbour of that name if there is one, else the host of that name on this
  node. A full address means itself. Two neighbours of that name on other nodes are
  ambiguous.

      iex> Tartarus.Host.resolve(:h2, [{:h2, :n2@pi}, {:h3, node()}])
      {:ok, {:h2, :n2@pi}}
      iex> Tartarus.Host.resolve(:h4, [{:h2, :n2@pi}])
      {:ok, {:h4, node()}}
      iex> Tartarus.Host.resolve(:h2, [{:h2, :n2@pi}, {:h2, :n3@pi}])
      {:error, {:ambiguous_host, :h2, [{:h2, :n2@pi}, {:h2, :n3@pi}]}}
  """
  @spec resolve(name() | t(), [t()]) :: {:ok, t()} | {:error, term()}
  def resolve({_name, _node} = host, _neighbours), do: {:ok, host}

  def resolve(name, neighbours) do
    case for({^name, _} = n <- neighbours, do: n) do
      [one] ->
        {:ok, one}

      [] ->
        {:ok, address(name)}

      many ->
        if address(name) in many,
          do: {:ok, address(name)},
          else: {:error, {:ambiguous_host, name, Enum.sort(many)}}
    end
  end

  @doc false
  # The pid of a host's server, local or remote.
  @spec whereis(name() | t()) :: {:ok, pid()} | {:error, {:unknown_host, term()}}
  def whereis(host) do
    if address?(host),
      do: Tartarus.Host.Directory.whereis(address(host)),
      else: {:error, {:unknown_host, host}}
  end

  @doc false
  # The tables and settings of a host on this node, read without calling its server.
  @spec local(name() | t()) :: {:ok, map()} | {:error, {:unknown_host, term()}}
  def local(host) do
    {name, node} = if address?(host), do: address(host), else: {host, nil}

    # The registry forgets a stopped host asynchronously: check that it is alive.
    with true <- node == node(),
         [{pid, %{} = info}] <- Registry.lookup(Tartarus.HostRegistry, {:host, name}),
         true <- Process.alive?(pid) do
      {:ok, info}
    else
      _ -> {:error, {:unknown_host, host}}
    end
  end

  @doc false
  # The pid of the current server of a host of this node, given the host map an agent holds
  # (Tartarus.Host.local/1): the server may have been restarted since the map was read (its
  # :pid is then a dead one, and stays the answer only if no server runs).
  @spec server(map()) :: pid()
  def server(%{pid: pid} = host) do
    # The ledger names the current server (Ledger.put_server/2): one small read, where the
    # registry would copy the host's whole map out with the pid.
    Tartarus.Ledger.server(host) || pid
  rescue
    # The host stopped (its ledger went with its warden).
    ArgumentError -> pid
  end

  @doc false
  # Runs `module.fun(host, args...)` for a host on this node, or remotely on the host's node
  # with :erpc (each function takes the host's full address first). A host that is gone (or
  # whose node is) answers `{:error, {:unknown_host, host}}`. Tartarus.Host.OnNode, Signal and
  # Broadcast keep their node-side functions in their own modules.
  @spec on_node(term(), module(), atom(), list()) :: term()
  def on_node(host, module, fun, args) do
    if address?(host) do
      {_, node} = host = address(host)

      if node == node() do
        try do
          apply(module, fun, [host | args])
        rescue
          # The host stopped while we read its tables.
          ArgumentError -> {:error, {:unknown_host, host}}
        end
      else
        try do
          :erpc.call(node, module, fun, [host | args], 10_000)
        catch
          _, _ -> {:error, {:unknown_host, host}}
        end
      end
    else
      {:error, {:unknown_host, host}}
    end
  end

  @doc false
  # Calls the overlay process of a host (`Tartarus.Overlay.Host`) with `{request, host}`:
  # directly on this node, through the node's door (`:tartarus_overlay`) on another, turning
  # a dead host or node into an error. Signal and Broadcast call it (by name: no xref cycle).
  @spec overlay_call(term(), term()) :: term()
  def overlay_call(host, request) do
    if address?(host) do
      {name, node} = host = address(host)

      dest = if node == node(), do: overlay_pid(name), else: {:tartarus_overlay, node}

      try do
        if dest == nil, do: exit(:noproc), else: GenServer.call(dest, {request, host}, 10_000)
      catch
        :exit, _ -> {:error, {:unknown_host, host}}
      end
    else
      {:error, {:unknown_host, host}}
    end
  end

  @doc false
  # The overlay process (Tartarus.Overlay.Host) of a host of this node, or nil.
  @spec overlay_pid(name()) :: pid() | nil
  def overlay_pid(name) do
    case Registry.lookup(Tartarus.HostRegistry, {:overlay, name}) do
      [{pid, _}] -> pid
      [] -> nil
    end
  end

  @doc false
  # Sends an overlay message (a signal relay, a broadcast) to host `to` (an address):
  # straight to its overlay process on this node, through its node's door
  # (`:tartarus_overlay`) otherwise; after `delay` ms of the clock when the link has a
  # latency (on this node counted in flight until the receiver takes it, for
  # Tartarus.Signal.settle/1).
  @spec overlay_send(t(), tuple(), non_neg_integer()) :: :ok
  def overlay_send({name, node}, msg, delay) do
    dest = if node == node(), do: overlay_pid(name), else: {:tartarus_overlay, node}

    cond do
      dest == nil ->
        :ok

      delay == 0 ->
        send(dest, msg)
        :ok

      node == node() ->
        overlay_in_flight(name, 1)
        Tartarus.Clock.send_after(dest, {:"$tartarus_delayed", msg}, delay)
        :ok

      true ->
        Tartarus.Clock.send_after(dest, msg, delay)
        :ok
    end
  end

  @doc false
  # Adds n to the overlay messages in flight to host `name` of this node; the count after.
  @spec overlay_in_flight(name(), integer()) :: integer()
  def overlay_in_flight(name, n) do
    :ets.update_counter(:tartarus_overlay_in_flight, name, n, {name, 0})
  rescue
    ArgumentError -> 0
  end

  @doc false
  # Calls a host's server, turning a dead host or node into an error.
  @spec call(name() | t(), term(), timeout()) :: term()
  def call(host, request, timeout \\ 5_000) do
    with {:ok, pid} <- whereis(host) do
      try do
        GenServer.call(pid, request, timeout)
      catch
        :exit, {:timeout, _} ->
          {:error, {:timeout, address(host)}}

        :exit, _ ->
          Tartarus.Host.Directory.forget(address(host))
          {:error, {:unknown_host, address(host)}}
      end
    end
  end
end
