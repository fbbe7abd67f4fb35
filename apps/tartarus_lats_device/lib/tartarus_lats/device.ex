defmodule TartarusLats.Device do
  @moduledoc """
  LATS on one real node: starts the node's database agent (`TartarusLats.DatabaseAgent`,
  named `"lats-db"`) on a host whose BLE receiver is attached as `:beacon`, and drives it
  every second of the node's own clock, as `TartarusLats.Deployment` drives the simulated
  ones: `{:sense, t}`, then `{:deliver, t, j}` while handshake messages go out (at most
  `:deliveries`), then `{:tick, t}`. Query agents released on the host (Where am I? Where is
  X?) then find the node's motion vectors in its store.

  A release node starts it from its configuration file as a service:

      services: [{TartarusLats.Device, node: :hall}]

  (the node's `TartarusNode.Boot` adds `host:`). Options: `:host` (required), `:node` (the
  LATS node's name, default the host's name), `:neighbours` (`%{node => host}`),
  `:tracker`, `:zone`, `:data_dir`, `:timeout` (as `TartarusLats.DatabaseAgent` takes them),
  `:period_ms` (default 1000), `:deliveries` (default 3).

  What differs from the emulator: each node counts its seconds on its own clock and there
  is no barrier across nodes, so a neighbour's handshake message is applied at the first
  delivery after it arrived (the database agent's rule for a late message), not in lockstep.
  A single node was tested here (a tty fed HM-10 scans, `test/release_test.exs`); several
  Pis linked as neighbours were not.
  """
  use GenServer

  alias Tartarus.Clock
  alias TartarusLats.DatabaseAgent

  @agent_keys [:neighbours, :tracker, :zone, :data_dir, :timeout, :cloud, :entrance]

  @doc "Starts the node's database agent and its one-second driver."
  @spec start_link(keyword()) :: GenServer.on_start()
  def start_link(opts), do: GenServer.start_link(__MODULE__, opts)

  @doc "The last second driven (0 before the first)."
  @spec second(GenServer.server()) :: non_neg_integer()
  def second(device), do: GenServer.call(device, :second)

  @impl true
  def init(opts) do
    host = Keyword.fetch!(opts, :host)
    node = Keyword.get_lazy(opts, :node, fn -> host_name(host) end)
    args = Map.new([node: node] ++ Keyword.take(opts, @agent_keys))

    case Tartarus.create_static_agent(host, DatabaseAgent, args, name: DatabaseAgent.agent_name()) do
      {:ok, _} ->
        period = Keyword.get(opts, :period_ms, 1000)
        Clock.send_after(self(), :second, period)

        {:ok,
         %{
           db: {DatabaseAgent.agent_name(), host},
           t: 0,
           period: period,
           deliveries: Keyword.get(opts, :deliveries, 3)
         }}

      {:error, reason} ->
        {:stop, {:database_agent_not_started, reason}}
    end
  end

  defp host_name({name, _node}), do: name
  defp host_name(name), do: name

  @impl true
  def handle_call(:second, _from, s), do: {:reply, s.t, s}

  @impl true
  def handle_info(:second, s) do
    t = s.t + 1
    {:ok, _} = Tartarus.request(s.db, {:sense, t})
    deliver(s, t, 1)
    {:ok, _} = Tartarus.request(s.db, {:tick, t})
    Clock.send_after(self(), :second, s.period)
    {:noreply, %{s | t: t}}
  end

  # The first delivery always; more while the agent still sends handshake messages.
  defp deliver(s, t, j) do
    {:ok, answer} = Tartarus.request(s.db, {:deliver, t, j})

    if j < s.deliveries and sent?(answer), do: deliver(s, t, j + 1), else: :ok
  end

  defp sent?({:ok, %{sent: sent}}) when map_size(sent) > 0, do: true
  defp sent?(_), do: false
end
