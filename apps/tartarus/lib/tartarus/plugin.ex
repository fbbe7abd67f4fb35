defmodule Tartarus.Plugin do
  @moduledoc """
  The plugin channel (Tartarus Plugin Channel): device drivers that agents reach through the
  host they are on.

  A plugin is a module implementing this behaviour, attached to a host under a name with
  `Tartarus.attach_plugin/3`. The host runs it in a process of its own. Agents use
  `Tartarus.Agent.read/2`, `Tartarus.Agent.write/2` and `Tartarus.Agent.subscribe/1`, which
  only ever reach the plugins of the host the agent is on: an agent that wants another
  node's sensor has to go there.

  Errors are values: `{:error, {:no_such_plugin, name}}` when the host has no such device,
  `{:error, {:bad_argument, arg}}` (returned by plugins) for arguments they do not take,
  `{:error, {:plugin_down, name}}` if the device's process died.

  ## Example

      Tartarus.attach_plugin(:a, :temp, {Tartarus.Plugin.SimSensor, signal: [20.5, 21.0]})
      # inside an agent on :a
      {:ok, 20.5} = Tartarus.Agent.read(:temp)

  Real devices (BLE receivers over UART, GPIO) implement the same behaviour in the firmware;
  `Tartarus.Plugin.SimSensor` is a simulated sensor with a scripted signal,
  `Tartarus.Plugin.GPIO` named pins (simulated here, `Circuits.GPIO` in the firmware),
  `Tartarus.Plugin.Serial` a serial line with a pluggable frame decoder.

  ## Capabilities

  What a robot can do (claws, a pusher, a camera) is described by its plugins, so agents can
  choose robots by what they can do. A plugin's description may list `:capabilities`
  (atoms), and any plugin can be given more when it is attached, with the option
  `capabilities:` (taken by the host, not passed to the plugin):

      Tartarus.attach_plugin(:claus, :claws,
        {Tartarus.Plugin.GPIO, pins: [grip: {17, :output}], capabilities: [:claws, :grip]})

      Tartarus.capabilities(:claus)         # from anywhere
      #=> %{claws: [:claws], grip: [:claws]}
      Tartarus.Agent.capabilities()         # inside an agent: its host's

  `capabilities/1` computes that map from a host's plugin list.
  """
  use GenServer
  require Tartarus.Events

  @typedoc "What a plugin says about itself."
  @type description :: %{
          required(:kind) => atom(),
          optional(:reads) => [term()],
          optional(:writes) => [term()],
          optional(:events) => [term()],
          optional(:capabilities) => [atom()],
          optional(atom()) => term()
        }

  @doc "Opens the device."
  @callback init(opts :: keyword()) :: {:ok, state :: term()} | {:error, term()}

  @doc "Describes the device's capabilities."
  @callback describe(state :: term()) :: description()

  @doc "Senses: reads a value."
  @callback read(args :: term(), state :: term()) ::
              {:ok, term(), term()} | {:error, term(), term()}

  @doc "Actuates: writes a value."
  @callback write(args :: term(), state :: term()) :: {:ok, term()} | {:error, term(), term()}

  @doc """
  Handles a message to the plugin's process (e.g. a timer, or data from a UART) and may
  produce events for subscribers.
  """
  @callback handle_info(msg :: term(), state :: term()) :: {:events, [term()], term()}

  @optional_callbacks handle_info: 2

  @doc """
  What a host's plugins can do: `%{capability => [plugin names]}` from a plugin list as
  `Tartarus.plugins/1` returns it (the `:capabilities` of each description).

      iex> Tartarus.Plugin.capabilities([
      ...>   {:arm, %{kind: :gpio, capabilities: [:claws, :grip]}},
      ...>   {:sonar, %{kind: :sensor, capabilities: [:ultrasonic]}},
      ...>   {:temp, %{kind: :sensor}},
      ...>   {:hand, %{kind: :gpio, capabilities: [:grip]}}
      ...> ])
      %{claws: [:arm], grip: [:arm, :hand], ultrasonic: [:sonar]}
  """
  @spec capabilities([{atom(), description()}]) :: %{atom() => [atom()]}
  def capabilities(plugins) when is_list(plugins) do
    for {name, %{capabilities: caps}} when is_list(caps) <- plugins,
        cap <- caps,
        reduce: %{} do
      acc -> Map.update(acc, cap, [name], &Enum.sort(Enum.uniq([name | &1])))
    end
  end

  @doc false
  def child_spec({host_name, name, module, opts}) do
    %{
      id: {:plugin, name},
      start: {__MODULE__, :start_link, [{host_name, name, module, opts}]},
      restart: :transient
    }
  end

  @doc false
  def start_link({host_name, name, module, opts}) do
    GenServer.start_link(__MODULE__, {name, module, opts},
      name: {:via, Registry, {Tartarus.HostRegistry, {:plugin, host_name, name}}}
    )
  end

  @doc false
  # Calls plugin `name` on `host` (which must be on this node).
  @spec call(Tartarus.host(), atom(), term()) :: term()
  def call({host_name, node}, name, request) when node == node() do
    case Registry.lookup(Tartarus.HostRegistry, {:plugin, host_name, name}) do
      [{pid, _}] ->
        try do
          GenServer.call(pid, request)
        catch
          :exit, _ -> {:error, {:plugin_down, name}}
        end

      [] ->
        {:error, {:no_such_plugin, name}}
    end
  end

  def call(host, name, _request), do: {:error, {:not_local, host, name}}

  @doc false
  @spec list(Tartarus.host_name()) :: [{atom(), description()}]
  # The host's own plugin supervisor's children, named through the registry's pid -> keys
  # index: the cost grows with this host's plugins, not with the node's hosts (a select over
  # the registry made Tartarus.status/1 cost about 1 ms per host on a node of 2,000).
  def list(host_name) do
    host_name
    |> plugin_pids()
    |> Enum.flat_map(fn pid ->
      for {:plugin, ^host_name, name} <- Registry.keys(Tartarus.HostRegistry, pid),
          do: {name, pid}
    end)
    |> Enum.flat_map(fn {name, pid} ->
      try do
        [{name, GenServer.call(pid, :describe)}]
      catch
        # A plugin stopping with its host.
        :exit, _ -> []
      end
    end)
    |> Enum.sort()
  end

  defp plugin_pids(host_name) do
    case Registry.lookup(Tartarus.HostRegistry, {:plugins, host_name}) do
      [{sup, _}] ->
        try do
          for {_, pid, _, _} <- DynamicSupervisor.which_children(sup), is_pid(pid), do: pid
        catch
          # The host is stopping.
          :exit, _ -> []
        end

      [] ->
        []
    end
  end

  @doc false
  # The last value a plugin of a host on this node read or announced, and when (system
  # time, ms): `%{value, at}`, or nil (none yet, or no such plugin). For the dashboard.
  @spec last_reading(Tartarus.host_name(), atom()) :: %{value: term(), at: integer()} | nil
  def last_reading(host_name, name) do
    case Registry.lookup(Tartarus.HostRegistry, {:plugin, host_name, name}) do
      [{pid, _}] -> GenServer.call(pid, :last_reading, 1_000)
      [] -> nil
    end
  catch
    :exit, _ -> nil
  end

  defp last(value), do: %{value: value, at: Tartarus.Clock.system_time(:millisecond)}

  @impl true
  def init({name, module, opts}) do
    {caps, opts} =
      if Keyword.keyword?(opts), do: Keyword.pop(opts, :capabilities, []), else: {[], opts}

    with true <- (is_list(caps) and Enum.all?(caps, &is_atom/1)) || {:bad_capabilities, caps},
         {:ok, state} <- module.init(opts) do
      {:ok,
       %{
         name: name,
         module: module,
         state: state,
         subscribers: %{},
         capabilities: caps,
         last: nil
       }}
    else
      {:bad_capabilities, caps} ->
        {:stop, {:bad_option, :capabilities, "expected a list of atoms, got: #{inspect(caps)}"}}

      {:error, reason} ->
        {:stop, reason}
    end
  end

  # The module's description, with the capabilities given at attach time added.
  defp describe(%{capabilities: []} = s), do: s.module.describe(s.state)

  defp describe(s) do
    d = s.module.describe(s.state)
    Map.put(d, :capabilities, Enum.uniq(Map.get(d, :capabilities, []) ++ s.capabilities))
  end

  @impl true
  def handle_call(msg, from, s) when not Tartarus.Events.is_from(from) do
    Tartarus.Events.drop(__MODULE__, :call, msg)
    {:noreply, s}
  end

  def handle_call(:describe, _from, s), do: {:reply, describe(s), s}

  def handle_call({:read, args}, _from, s) do
    case s.module.read(args, s.state) do
      {:ok, value, state} -> {:reply, {:ok, value}, %{s | state: state, last: last(value)}}
      {:error, reason, state} -> {:reply, {:error, reason}, %{s | state: state}}
    end
  end

  def handle_call(:last_reading, _from, s), do: {:reply, s.last, s}

  def handle_call({:write, args}, _from, s) do
    case s.module.write(args, s.state) do
      {:ok, state} -> {:reply, :ok, %{s | state: state}}
      {:error, reason, state} -> {:reply, {:error, reason}, %{s | state: state}}
    end
  end

  def handle_call({:subscribe, pid}, _from, s) when is_pid(pid) do
    if Map.has_key?(s.subscribers, pid) do
      {:reply, :ok, s}
    else
      {:reply, :ok, %{s | subscribers: Map.put(s.subscribers, pid, Process.monitor(pid))}}
    end
  end

  # Anything else is answered, dropped and counted, never a crash.
  def handle_call(msg, _from, s) do
    Tartarus.Events.drop(__MODULE__, :call, msg)
    {:reply, {:error, :unexpected_call}, s}
  end

  @impl true
  def handle_cast(msg, s) do
    Tartarus.Events.drop(__MODULE__, :cast, msg)
    {:noreply, s}
  end

  @impl true
  # Only the monitors this server made count: a forged :DOWN goes to the plugin like any message.
  def handle_info({:DOWN, ref, :process, pid, _}, s)
      when is_map_key(s.subscribers, pid) and :erlang.map_get(pid, s.subscribers) == ref do
    {:noreply, %{s | subscribers: Map.delete(s.subscribers, pid)}}
  end

  def handle_info(msg, s) do
    if function_exported?(s.module, :handle_info, 2) do
      {:events, events, state} = s.module.handle_info(msg, s.state)

      for event <- events, pid <- Map.keys(s.subscribers) do
        send(pid, {:plugin_event, s.name, event})
      end

      s = if events == [], do: s, else: %{s | last: last(List.last(events))}
      {:noreply, %{s | state: state}}
    else
      {:noreply, s}
    end
  end
end
