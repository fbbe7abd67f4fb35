defmodule TartarusFirmware.Distribution do
  @moduledoc """
  Starts Erlang distribution at boot, over TLS with mutual certificates
  (`-proto_dist tartarus_tls` in `rel/vm.args.eex`, see `Tartarus.Security.TLSDist`).

  The node is `<node_basename>@<host name>.local` (`tartarus@tartarus-1a2b.local`; mdns_lite
  answers for `<host name>.local`). Its files are read from `<data>/certs` (default
  `/data/tartarus/certs`, put there with `mix tartarus.gen.certs` and `sftp`, see
  docs/devices.md):

    * `node.pem` and `node.key` - this node's certificate and key (the files
      `mix tartarus.gen.certs --nodes tartarus@tartarus-1a2b.local --hosts tartarus-1a2b.local`
      writes as `tartarus@tartarus-1a2b.local.pem` and `.key`, renamed; `node_name/0`, in
      an ssh shell on the Pi, tells the name to issue it for);
    * `ca.pem` - the cluster's CA, which every peer's certificate must chain to.

  From them it writes `<data>/ssl_dist.conf` (the option file `vm.args` names), starts
  `epmd` and then the node. Without certificates it logs why and starts no distribution:
  the Pi is then reachable over ssh only, to receive them.
  """
  use GenServer
  require Logger

  @doc false
  def start_link(_), do: GenServer.start_link(__MODULE__, [], name: __MODULE__)

  @doc "The node name this Pi takes: `<basename>@<host name>.local`."
  @spec node_name() :: atom()
  def node_name do
    base = Application.get_env(:tartarus_firmware, :node_basename, "tartarus")
    :"#{base}@#{TartarusFirmware.host()}.local"
  end

  @doc """
  Writes the TLS distribution option file from the certificates in `certs_dir`; returns
  its path, or `{:error, {:missing, files}}`.
  """
  @spec write_optfile(Path.t(), Path.t()) :: {:ok, Path.t()} | {:error, term()}
  def write_optfile(certs_dir, path) do
    missing = Enum.reject(["node.pem", "node.key", "ca.pem"], &File.exists?(Path.join(certs_dir, &1)))

    if missing == [] do
      terms = Tartarus.Security.TLSDist.optfile_terms("node", certs_dir)
      text = :io_lib.format(~c"~tp.~n", [terms])
      File.write!(path, ["%% written at boot by TartarusFirmware.Distribution\n", text])
      {:ok, path}
    else
      {:error, {:missing, Enum.map(missing, &Path.join(certs_dir, &1))}}
    end
  end

  @impl true
  def init([]) do
    if Application.get_env(:tartarus_firmware, :distribution, false) and not Node.alive?() do
      data = TartarusFirmware.data_dir()

      with {:ok, _} <- write_optfile(Path.join(data, "certs"), Path.join(data, "ssl_dist.conf")),
           {_, 0} <- System.cmd("epmd", ["-daemon"]),
           {:ok, _} <- Node.start(node_name(), :longnames) do
        Logger.info("tartarus: distribution started as #{node()} (TLS)")
      else
        other -> Logger.warning("tartarus: no distribution: #{inspect(other)}")
      end
    end

    {:ok, %{}}
  end
end
