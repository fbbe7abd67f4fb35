defmodule Mix.Tasks.Tartarus.Node do
  @shortdoc "Starts a named node with a Tartarus host, for iex --remsh"

  @schema [
    name: [type: :string, required: true, doc: "the node's short name; the node is `NAME@<hostname>`"],
    host: [type: :string, default: "main", doc: "the host's name"],
    neighbours: [type: :string, doc: "comma-separated `host:node` addresses to link to"],
    cookie: [type: :string, default: "tartarus", doc: "the distribution cookie"],
    sensor: [
      type: :string,
      doc: "attach a simulated sensor plugin under this name (a sine-like script)"
    ],
    ble: [
      type: :string,
      doc:
        "attach the BLE receiver on this serial device (e.g. `/dev/ttyUSB0`) as plugin `:beacon` (see below)"
    ],
    serial: [
      type: :string,
      doc: "attach a serial device read as text lines as plugin `:serial`"
    ],
    speed: [type: :pos_integer, default: 9600, doc: "baud of `--ble` and `--serial`"],
    dashboard: [
      type: :non_neg_integer,
      doc: "serve the web dashboard (`TartarusTools.Dashboard`) on this port"
    ],
    dashboard_bind: [
      type: :string,
      default: "127.0.0.1",
      doc: "the address the dashboard listens on"
    ],
    dashboard_token_file: [
      type: :string,
      doc: "read the dashboard's action token from this file (default: a random one, printed)"
    ],
    dashboard_hosts: [
      type: :string,
      doc:
        "comma-separated names the dashboard also answers to in `Host`/`Origin` (e.g. `pi.local` with `--dashboard-bind 0.0.0.0`); `localhost`, the loopback addresses and the address a client connected to always work"
    ]
  ]
  @moduledoc """
  Starts this VM as a named BEAM node running one Tartarus host, links it to neighbour
  hosts on other nodes, and keeps running until interrupted.

      ELIXIR_ERL_OPTIONS="-connect_all false" mix tartarus.node --name n1 --host h1
      ELIXIR_ERL_OPTIONS="-connect_all false" mix tartarus.node --name n2 --host h2 --neighbours h1:n1@$(hostname -s)

  Options (flags are the keys with dashes):

  #{TartarusTools.CLI.flag_docs(@schema)}

  ## Devices

  `--serial PATH` attaches `Tartarus.Plugin.Serial` (a tty configured with `stty`, read
  through an Erlang port, reopened when the device comes back) with its line decoder.

  `--ble PATH` attaches a BLE receiver on that tty as plugin `:beacon`. Which receiver is
  an application's choice, so this task names none: it calls the function configured as
  `config :tartarus_tools, :ble_plugin, {module, function}` with the path and
  `[speed: baud]`, which returns the plugin spec. The umbrella's `config/config.exs` sets
  LATS's HM-10 receiver, so in this repository

      ELIXIR_ERL_OPTIONS="-connect_all false" mix tartarus.node --name n1 --host h1 --ble /dev/ttyUSB0

  gives the host an HM-10 that a LATS database agent reads (`Tartarus.read_plugin(:h1,
  :beacon, :counts)` shows what arrived). See `docs/devices.md`.

  The host itself starts with `Tartarus.start_host/2`'s defaults (see its documentation),
  among them the admission policy's finite limits.

  Then attach a shell and drive it with the `Tartarus` API:

      iex --sname me --cookie tartarus --remsh n1@<hostname>
      iex> Tartarus.status(:h1)

  `-connect_all false` keeps nodes from forming a full mesh (they connect only to the nodes
  their hosts talk to); it must be given to the VM at boot, hence `ELIXIR_ERL_OPTIONS`.
  """
  use TartarusTools.CLI

  @impl true
  def run(argv) do
    opts = TartarusTools.CLI.options!(argv, @schema, "tartarus.node")
    neighbours = parse_neighbours(opts[:neighbours])
    name = opts[:name]
    _ = System.cmd("epmd", ["-daemon"])

    case Node.start(String.to_atom(name), :shortnames) do
      {:ok, _} ->
        :ok

      {:error, reason} ->
        Mix.raise("mix tartarus.node: cannot start node #{name}: #{inspect(reason)}")
    end

    Node.set_cookie(String.to_atom(opts[:cookie]))
    Mix.Task.run("app.start")

    unless :init.get_argument(:connect_all) == {:ok, [[~c"false"]]} do
      Mix.shell().info("note: started without -connect_all false; nodes may form a full mesh")
    end

    host_name = String.to_atom(opts[:host])
    plugins = plugins!(opts)

    case Tartarus.start_host(host_name, neighbours: neighbours, plugins: plugins) do
      {:ok, host} ->
        Mix.shell().info(
          "host #{inspect(host)} running; neighbours: #{inspect(Tartarus.neighbours(host))}"
        )

        Mix.shell().info(
          "attach with: iex --sname me --cookie #{Node.get_cookie()} --remsh #{node()}"
        )

        if opts[:dashboard], do: start_dashboard(opts)

        Process.sleep(:infinity)

      {:error, reason} ->
        Mix.raise("mix tartarus.node: cannot start host: #{inspect(reason)}")
    end
  end

  @doc false
  # The plugins the flags ask for, as `{name, spec}`; raises Mix.Error naming the flag.
  @spec plugins!(keyword()) :: [{atom(), {module(), keyword()}}]
  def plugins!(opts) do
    sensor =
      for s <- List.wrap(opts[:sensor]) do
        {String.to_atom(s),
         {Tartarus.Plugin.SimSensor,
          signal: Enum.map(0..59, &(20 + :math.sin(&1 / 10) * 5)), unit: "°C"}}
      end

    serial =
      for path <- List.wrap(opts[:serial]),
          do: {:serial, {Tartarus.Plugin.Serial, device: path, speed: opts[:speed] || 9600}}

    ble = for path <- List.wrap(opts[:ble]), do: {:beacon, ble_plugin!(path, opts[:speed])}
    sensor ++ serial ++ ble
  end

  defp ble_plugin!(path, speed) do
    with {m, f} when is_atom(m) and is_atom(f) <-
           Application.get_env(:tartarus_tools, :ble_plugin),
         true <- Code.ensure_loaded?(m) and function_exported?(m, f, 2),
         {module, plugin_opts} = spec when is_atom(module) and is_list(plugin_opts) <-
           apply(m, f, [path, [speed: speed || 9600]]) do
      spec
    else
      _ ->
        Mix.raise(
          "mix tartarus.node: --ble needs a BLE receiver: configure :tartarus_tools, :ble_plugin as {module, function} (function(path, [speed: baud]) returns a plugin spec), got: #{inspect(Application.get_env(:tartarus_tools, :ble_plugin))}"
        )
    end
  end

  defp start_dashboard(opts) do
    bind =
      case :inet.parse_address(String.to_charlist(opts[:dashboard_bind])) do
        {:ok, ip} -> ip
        _ -> Mix.raise("mix tartarus.node: --dashboard-bind expects an IP address, got: #{opts[:dashboard_bind]}")
      end

    hosts =
      (opts[:dashboard_hosts] || "") |> String.split(",", trim: true) |> Enum.map(&String.trim/1)

    dash_opts =
      [port: opts[:dashboard], bind: bind, hosts: hosts] ++
        if(opts[:dashboard_token_file], do: [token_file: opts[:dashboard_token_file]], else: [])

    case TartarusTools.Dashboard.start(dash_opts) do
      {:ok, dash} -> Mix.shell().info(TartarusTools.Dashboard.banner(dash))
      {:error, reason} -> Mix.raise("mix tartarus.node: cannot start the dashboard: #{inspect(reason)}")
    end
  end

  defp parse_neighbours(nil), do: []

  defp parse_neighbours(list) do
    list
    |> String.split(",", trim: true)
    |> Enum.map(fn item ->
      case String.split(item, ":", parts: 2) do
        [h, n] -> {String.to_atom(h), String.to_atom(n)}
        _ -> Mix.raise("mix tartarus.node: --neighbours expects host:node items, got: #{item}")
      end
    end)
  end
end
