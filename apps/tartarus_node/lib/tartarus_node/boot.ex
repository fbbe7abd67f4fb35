defmodule TartarusNode.Boot do
  @moduledoc """
  The configured node's host: started with the configuration's plugins, persistence and
  trust list (`TartarusNode.Config.host_options/1`), its neighbours linked as soon as they
  answer (a device may boot before its neighbours: each missing link is tried again every
  2 s), the dashboard when `dashboard:` is set, and the configured `services:`
  (`module.start_link(opts ++ [host: host])`, each under `TartarusNode.Supervisor`).

  It logs one line when the host runs (`tartarus: host {h1, :"tartarus@198.18.0.1"}
  running; plugins: ...`). A host that cannot start (its data directory cannot be made, a
  plugin's device refuses to open) stops the node with one line on standard error and
  status 1, not a crash report and an `erl_crash.dump`:

      tartarus: cannot start host pi1: {:gpio_open_failed, :led, 17, :no_gpio_backend}
  """
  use GenServer
  require Logger

  alias Tartarus.Clock

  @retry_ms 2_000

  @doc false
  def start_link(config), do: GenServer.start_link(__MODULE__, config, name: __MODULE__)

  @doc "The host this node runs, `{name, node()}`."
  @spec host() :: Tartarus.host()
  def host, do: GenServer.call(__MODULE__, :host)

  @doc "The configured neighbours not linked yet."
  @spec missing_neighbours() :: [Tartarus.host()]
  def missing_neighbours, do: GenServer.call(__MODULE__, :missing)

  @impl true
  def init(config) do
    boot(config)
  rescue
    e -> fail("tartarus: cannot start host #{config.host}: #{Exception.message(e)}")
  catch
    kind, reason -> fail("tartarus: cannot start host #{config.host}: #{kind} #{inspect(reason)}")
  end

  defp boot(config) do
    with :ok <- make_data_dir(config.data_dir),
         {:ok, host} <- start_host(config) do
      Logger.notice(
        "tartarus: host #{inspect(host)} running; plugins: " <>
          Enum.map_join(config.plugins, ", ", fn {n, {m, _}} -> "#{n} (#{inspect(m)})" end)
      )

      dash = if config.dashboard, do: start_dashboard(config.dashboard)
      send(self(), :link)

      {:ok, %{host: host, missing: config.neighbours, dashboard: dash},
       {:continue, {:services, Map.get(config, :services, [])}}}
    else
      {:error, why} -> fail("tartarus: cannot start host #{config.host}: #{why}")
    end
  end

  defp make_data_dir(nil), do: :ok

  defp make_data_dir(dir) do
    case File.mkdir_p(dir) do
      :ok -> :ok
      {:error, reason} -> {:error, "data_dir: cannot make #{dir} (#{:file.format_error(reason)})"}
    end
  end

  defp start_host(config) do
    with {:ok, opts} <- TartarusNode.Config.host_options(config),
         {:ok, host} <- Tartarus.start_host(config.host, opts) do
      {:ok, host}
    else
      {:error, reason} when is_binary(reason) -> {:error, reason}
      {:error, reason} -> {:error, inspect(reason)}
    end
  end

  # The node was started to run this host and cannot: one line, status 1 (the release's
  # unit does not restart a node that exits 1 in a loop).
  defp fail(line) do
    IO.puts(:stderr, String.replace(line, ~r/\s*[\r\n]\s*/, " "))
    System.halt(1)
  end

  # After init: the supervisor starting this process is free again to start the services.
  @impl true
  def handle_continue({:services, services}, s) do
    for {module, opts} <- services do
      spec = %{id: {:service, module}, start: {module, :start_link, [opts ++ [host: s.host]]}}

      case Supervisor.start_child(TartarusNode.Supervisor, spec) do
        {:ok, _} -> :ok
        {:error, reason} -> fail("tartarus: cannot start service #{inspect(module)}: #{inspect(reason)}")
      end
    end

    {:noreply, s}
  end

  @impl true
  def handle_call(:host, _from, s), do: {:reply, s.host, s}
  def handle_call(:missing, _from, s), do: {:reply, s.missing, s}

  @impl true
  def handle_info(:link, s) do
    missing = Enum.reject(s.missing, &(Tartarus.connect(s.host, &1) == :ok))
    if missing != [], do: Clock.send_after(self(), :link, @retry_ms)
    {:noreply, %{s | missing: missing}}
  end

  defp start_dashboard(opts) do
    with {:ok, module} <- TartarusNode.Config.dashboard_module(),
         {:ok, dash} <- module.start(opts) do
      Logger.notice(module.banner(dash))
      dash
    else
      {:error, reason} ->
        Logger.error("tartarus: cannot start the dashboard: #{inspect(reason)}")
        nil
    end
  end
end
