defmodule TartarusFirmware.Node do
  @moduledoc """
  Starts this Pi's Tartarus host (`TartarusFirmware.host/0`) with the configured plugins,
  persistence under `<data>/host` and, if `<data>/trusted` holds issuers' public keys, a
  trust list: only agents signed by those issuers are admitted.
  """
  use GenServer
  require Logger

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

  @impl true
  def init([]) do
    File.mkdir_p(Path.join(TartarusFirmware.data_dir(), "host"))

    case Tartarus.start_host(TartarusFirmware.host(), host_options()) do
      {:ok, host} ->
        Logger.info("tartarus: host #{inspect(host)} started")
        {:ok, host}

      {:error, reason} ->
        {:stop, {:host_not_started, reason}}
    end
  end
end
