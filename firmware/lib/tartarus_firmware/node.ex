defmodule TartarusFirmware.Node do
  @moduledoc """
  Starts this Pi's Tartarus host (`TartarusFirmware.host/0`) with the configured plugins,
  persistence under `<data>/host` and, if `<data>/trusted` holds issuers' public keys, a
  trust list: only agents signed by those issuers are admitted. Then it links the
  configured neighbours (`config :tartarus_firmware, neighbours: [pi2: :"tartarus@tartarus-3c4d.local"]`)
  as soon as each answers: a Pi may boot before its neighbours, so each missing link is
  tried again every 2 s. Last it starts the configured services, as a release node does
  (`config :tartarus_firmware, services: [{TartarusLats.Device, []}]`:
  `module.start_link(opts ++ [host: host])`, under a supervisor of this process's own, which
  restarts a service that dies and stops them all when this process stops).
  """
  use GenServer
  require Logger

  alias Tartarus.Clock

  @retry_ms 2_000

  @doc false
  def start_link(_), do: GenServer.start_link(__MODULE__, [], name: __MODULE__)

  @doc "The options `Tartarus.start_host/2` gets on this Pi."
  @spec host_options() :: keyword()
  def host_options do
    data = TartarusFirmware.data_dir()
    plugins = Application.get_env(:tartarus_firmware, :plugins, [])
    base = [plugins: plugins, data_dir: Path.join(data, "host")]

    case Tartarus.Security.TrustList.from_dir(Path.join(data, "trusted")) do
      {:ok, trust} ->
        if Tartarus.Security.TrustList.size(trust) > 0,
          do: base ++ [security: [trust: trust]],
          else: base

      {:error, _} ->
        base
    end
  end

  @doc "The configured neighbours, `[{host name, node}]`."
  @spec neighbours() :: [{atom(), node()}]
  def neighbours, do: Application.get_env(:tartarus_firmware, :neighbours, [])

  @doc "The configured neighbours not linked yet."
  @spec missing_neighbours() :: [{atom(), node()}]
  def missing_neighbours, do: GenServer.call(__MODULE__, :missing)

  @impl true
  def init([]) do
    File.mkdir_p(Path.join(TartarusFirmware.data_dir(), "host"))

    case Tartarus.start_host(TartarusFirmware.host(), host_options()) do
      {:ok, host} ->
        Logger.info("tartarus: host #{inspect(host)} started")
        send(self(), :link)
        {:ok, %{host: host, missing: neighbours()}, {:continue, :services}}

      {:error, reason} ->
        {:stop, {:host_not_started, reason}}
    end
  end

  @impl true
  def handle_continue(:services, s) do
    specs =
      for {module, opts} <- Application.get_env(:tartarus_firmware, :services, []),
          do: %{id: module, start: {module, :start_link, [opts ++ [host: s.host]]}}

    {:ok, _} = Supervisor.start_link(specs, strategy: :one_for_one)
    {:noreply, s}
  end

  @impl true
  def handle_call(:missing, _from, s), do: {:reply, s.missing, s}

  @impl true
  def handle_info(:link, s) do
    missing = Enum.reject(s.missing, &(Tartarus.connect(s.host, &1) == :ok))
    if missing != [], do: Clock.send_after(self(), :link, @retry_ms)
    {:noreply, %{s | missing: missing}}
  end
end
