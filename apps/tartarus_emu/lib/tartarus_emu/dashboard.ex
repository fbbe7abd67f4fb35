defmodule TartarusEmu.Dashboard do
  @moduledoc """
  The emulator's side of the web dashboard (`TartarusDashboard`): an emulated
  network's hosts (on whichever BEAM node each lives), its topology's links and whether
  each is live, and the link actions carried out with `TartarusEmu.Network`
  (`break_link/3`, `heal_link/3`, `isolate/2`, `rejoin/2`).

      {:ok, net} = TartarusEmu.Network.start(TartarusEmu.Topology.grid(3, 3))
      {:ok, dash} = TartarusEmu.Dashboard.start_link(net, port: 4040)
      IO.puts(TartarusDashboard.banner(dash))

  A host's id on the page and in the JSON API is its topology node's name as a string;
  positions of the topology (if it has them) place the hosts on the page.

  A scenario that builds a new network for each step (the warehouse's experiments start a
  floor per point) gives a function instead of a network: it is called on every page
  refresh and returns the network to show now, or `nil` (none: no hosts, no links, and
  link actions are refused with `{:error, :no_network}`).
  """

  @behaviour TartarusDashboard.Emulation

  alias TartarusEmu.Network

  @typedoc "A network, or a function returning the one to show now (`nil`: none)."
  @type source :: Network.t() | (() -> Network.t() | nil)

  @doc """
  Starts a dashboard (linked to the caller) showing `net` (a `t:source/0`): the options of
  `TartarusDashboard`, with `:emulation` set to this module and `net`.
  """
  @spec start_link(source(), keyword()) :: GenServer.on_start()
  def start_link(net, opts \\ [])

  def start_link(net, opts) when is_struct(net, Network) or is_function(net, 0) do
    TartarusDashboard.start_link(Keyword.put(opts, :emulation, {__MODULE__, net}))
  end

  @doc """
  As `start_link/2`, not linked: a dashboard that cannot start (a port in use) returns
  `{:error, reason}` to the caller rather than taking it down.
  """
  @spec start(source(), keyword()) :: GenServer.on_start()
  def start(net, opts \\ [])

  def start(net, opts) when is_struct(net, Network) or is_function(net, 0) do
    TartarusDashboard.start(Keyword.put(opts, :emulation, {__MODULE__, net}))
  end

  @doc """
  Starts a dashboard (not linked) for `net` from a runner's `dashboard:` value, a port or
  dashboard options, with `panels` (`[{module, arg}]`), and prints its address and token
  on `device`. Returns `{:ok, dash}`, or `{:error, message}` (a bad option, a port in use).
  """
  @spec serve(source(), non_neg_integer() | keyword(), [{module(), term()}], IO.device()) ::
          {:ok, pid()} | {:error, String.t()}
  def serve(net, spec, panels, device \\ :standard_error) do
    opts = if is_integer(spec), do: [port: spec], else: spec

    case start(net, Keyword.put_new(opts, :panels, panels)) do
      {:ok, dash} ->
        IO.puts(device, TartarusDashboard.banner(dash))
        {:ok, dash}

      {:error, reason} when is_binary(reason) ->
        {:error, reason}

      {:error, reason} ->
        {:error, "dashboard: the web server did not start: #{inspect(reason)}"}
    end
  end

  @impl true
  @doc "The network's hosts in topology order, `up` unless isolated or killed."
  def hosts(net) when is_function(net, 0), do: if(n = net.(), do: hosts(n), else: [])

  def hosts(%Network{} = net) do
    topo = net.topology

    Enum.map(topo.nodes, fn n ->
      %{
        id: to_string(n),
        host: Network.host(net, n),
        up: Network.up?(net, n),
        pos: pos(topo.positions[n]),
        floor: topo.floors[n]
      }
    end)
  end

  defp pos({x, y}), do: {x, y}
  defp pos({x, y, _z}), do: {x, y}
  defp pos(_), do: nil

  @impl true
  @doc "The topology's edges, sorted, each `up` when live."
  def links(net) when is_function(net, 0), do: if(n = net.(), do: links(n), else: [])

  def links(%Network{} = net) do
    net.topology.edges
    |> Enum.sort()
    |> Enum.map(fn {a, b} -> %{a: to_string(a), b: to_string(b), up: Network.live?(net, a, b)} end)
  end

  @impl true
  @doc "Breaks or heals a link, isolates a host or lets it rejoin."
  def act(net, action, params) when is_function(net, 0) do
    if n = net.(), do: act(n, action, params), else: {:error, :no_network}
  end

  def act(%Network{} = net, action, params) do
    names = Map.new(net.topology.nodes, &{to_string(&1), &1})

    case {action, params} do
      {:break_link, %{a: a, b: b}} -> Network.break_link(net, names[a], names[b])
      {:heal_link, %{a: a, b: b}} -> Network.heal_link(net, names[a], names[b])
      {:isolate, %{host: h}} -> Network.isolate(net, names[h])
      {:rejoin, %{host: h}} -> Network.rejoin(net, names[h])
      _ -> {:error, :unknown_action}
    end
  end
end
