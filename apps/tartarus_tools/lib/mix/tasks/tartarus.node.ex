defmodule Mix.Tasks.Tartarus.Node do
  @shortdoc "Starts a named node with a Tartarus host, for iex --remsh"

  @schema [
    name: [
      type: :string,
      required: true,
      doc: "the node's short name; the node is `NAME@<hostname>`"
    ],
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
      doc: "serve the web dashboard (`TartarusDashboard`) on this port"
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
    tls_certs: [
      type: :string,
      doc:
        "run over TLS distribution with the certificates in this directory (made by `mix tartarus.gen.certs`); the VM must be started with the TLS flags, which the task prints if it was not (see \"TLS\" below)"
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
  an application's choice, so this task names none: the application that brings one says
  so in its environment (`tartarus_ble_plugin: {module, function}`, as LATS's `mix.exs`
  does; see `Tartarus.Plugin.Shorthand`, which parses these flags as a node's
  configuration file's `{:ble, path}`, `{:serial, path}` and `{:sensor, opts}`), so in
  this repository

      ELIXIR_ERL_OPTIONS="-connect_all false" mix tartarus.node --name n1 --host h1 --ble /dev/ttyUSB0

  gives the host an HM-10 that a LATS database agent reads: the serial plugin,
  `Tartarus.Plugin.Serial`, with LATS's decoder of the receiver's answers
  (`TartarusLats.HM10.Receiver`, which also polls it); `Tartarus.read_plugin(:h1, :beacon,
  :counts)` shows what arrived. See `docs/devices.md`.

  A device path that does not exist is reported at once (`warning: --ble /dev/ttyUSB0: no
  such file`); the plugin is still attached and opens the device when it appears. At start
  the task lists the plugins it attached, with a serial plugin's decoder
  (`plugins: beacon (Tartarus.Plugin.Serial, decoder TartarusLats.HM10.Receiver)` in this
  repository, or `plugins: none`).

  ## TLS

  Distribution over TLS (`Tartarus.Security.TLSDist`) is chosen when the VM boots
  (`-proto_dist`), before this task runs, so `--tls-certs DIR` cannot switch it on by
  itself. It checks instead: that `DIR/NAME.ssl_dist.conf` exists (made by
  `mix tartarus.gen.certs --nodes NAME,me --out DIR`) and that the VM was started with
  `-proto_dist tartarus_tls`; if not, it stops and prints the exact command to run, with the
  flags of `Tartarus.Security.TLSDist.erl_flags/2` in `ELIXIR_ERL_OPTIONS`:

      mix tartarus.node --name n1 --host h1 --tls-certs certs
      # prints: ELIXIR_ERL_OPTIONS="-connect_all false -proto_dist tartarus_tls -ssl_dist_optfile /abs/certs/n1.ssl_dist.conf -pa /abs/_build/dev/lib/tartarus/ebin" mix tartarus.node --name n1 --host h1 --tls-certs certs

  Once the node runs over TLS, the attach hint it prints carries the TLS flags of the shell's
  own certificate (`DIR/me.ssl_dist.conf`; the task says so when that file is missing).

  The host itself starts with `Tartarus.start_host/2`'s defaults (see its documentation),
  among them the admission policy's finite limits.

  Then attach a shell and drive it with the `Tartarus` API:

      iex --sname me --cookie tartarus --remsh n1@<hostname>
      iex> Tartarus.status(:h1)

  `-connect_all false` keeps nodes from forming a full mesh (they connect only to the nodes
  their hosts talk to); it must be given to the VM at boot, hence `ELIXIR_ERL_OPTIONS`.
  """
  use TartarusTools.CLI, out: false

  @impl true
  def run(argv) do
    opts = TartarusTools.CLI.options!(argv, @schema, "tartarus.node")
    neighbours = parse_neighbours(opts[:neighbours])
    name = opts[:name]
    tls_check!(opts, argv, :init.get_argument(:proto_dist))
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
    Enum.each(device_warnings(opts), &Mix.shell().info/1)

    case Tartarus.start_host(host_name, neighbours: neighbours, plugins: plugins) do
      {:ok, host} ->
        Mix.shell().info(
          "host #{inspect(host)} running; neighbours: #{inspect(Tartarus.neighbours(host))}"
        )

        Mix.shell().info(plugins_line(plugins))

        Enum.each(
          attach_hint(Node.get_cookie(), node(), opts[:tls_certs]),
          &Mix.shell().info/1
        )

        if opts[:dashboard], do: start_dashboard(opts)

        Tartarus.Clock.sleep(:infinity)

      {:error, reason} ->
        Mix.raise("mix tartarus.node: cannot start host: #{inspect(reason)}")
    end
  end

  @doc false
  # The plugins the flags ask for, as `{name, spec}`; raises Mix.Error naming the flag.
  @spec plugins!(keyword()) :: [{atom(), {module(), keyword()}}]
  def plugins!(opts) do
    sensor = for s <- List.wrap(opts[:sensor]), do: {String.to_atom(s), {:sensor, unit: "°C"}}

    serial =
      for path <- List.wrap(opts[:serial]),
          do: {:serial, {:serial, path, speed: opts[:speed] || 9600}}

    ble = for path <- List.wrap(opts[:ble]), do: {:beacon, {:ble, path, speed: opts[:speed] || 9600}}

    # The shorthands of a node's configuration file, parsed by the same function
    # (Tartarus.Plugin.Shorthand); a missing device is a warning here (device_warnings/1).
    for {name, spec} <- sensor ++ serial ++ ble do
      case Tartarus.Plugin.Shorthand.parse(name, spec, Keyword.take(opts, [:ble_receiver])) do
        {:ok, spec} -> {name, spec}
        {:error, line} -> Mix.raise("mix tartarus.node: --#{flag(spec)}: #{line}")
      end
    end
  end

  defp flag({kind, _, _}), do: kind
  defp flag({:sensor, _}), do: :sensor

  @doc false
  # One line naming the plugins the host was started with.
  @spec plugins_line([{atom(), {module(), keyword()}}]) :: String.t()
  def plugins_line([]), do: "plugins: none"

  def plugins_line(plugins) do
    "plugins: " <>
      Enum.map_join(plugins, ", ", fn {name, {module, opts}} ->
        decoder = if opts[:decoder], do: ", decoder #{inspect(opts[:decoder])}", else: ""
        "#{name} (#{inspect(module)}#{decoder})"
      end)
  end

  @doc false
  # A warning per device flag whose path does not exist (the plugin retries until it appears).
  @spec device_warnings(keyword()) :: [String.t()]
  def device_warnings(opts) do
    for flag <- [:ble, :serial], path <- List.wrap(opts[flag]), not File.exists?(path) do
      "warning: --#{flag} #{path}: no such file; the plugin is attached and opens the device when it appears"
    end
  end

  @doc false
  # The lines that tell how to attach a remote shell: with TLS flags when the node runs over
  # TLS distribution (`certs_dir` given), from the shell's own certificate `me`.
  @spec attach_hint(atom(), node(), Path.t() | nil) :: [String.t()]
  def attach_hint(cookie, node, nil),
    do: ["attach with: iex --sname me --cookie #{cookie} --remsh #{node}"]

  def attach_hint(cookie, node, certs_dir) do
    flags = Enum.join(Tartarus.Security.TLSDist.erl_flags("me", certs_dir), " ")
    optfile = Tartarus.Security.TLSDist.optfile_path("me", certs_dir)

    missing =
      if File.exists?(optfile),
        do: [],
        else: [
          "note: #{optfile} is missing: the shell needs a certificate of its own (mix tartarus.gen.certs --nodes #{short(node)},me --out #{certs_dir})"
        ]

    missing ++
      [~s(attach with: iex --sname me --cookie #{cookie} --erl "#{flags}" --remsh #{node})]
  end

  defp short(node), do: node |> Atom.to_string() |> String.split("@") |> hd()

  @doc false
  # With `--tls-certs DIR`: raises (printing the exact command to run) unless the option file
  # of the node exists and the VM was started with `-proto_dist tartarus_tls`.
  @spec tls_check!(keyword(), [String.t()], {:ok, [[charlist()]]} | :error) :: :ok
  def tls_check!(opts, argv, proto_dist) do
    case opts[:tls_certs] do
      nil ->
        :ok

      dir ->
        name = opts[:name]
        optfile = Tartarus.Security.TLSDist.optfile_path(name, dir)

        cond do
          not File.exists?(optfile) ->
            Mix.raise(
              "mix tartarus.node: --tls-certs #{dir}: #{optfile} not found; make it with: mix tartarus.gen.certs --nodes #{name},me --out #{dir}"
            )

          proto_dist == {:ok, [[~c"tartarus_tls"]]} ->
            :ok

          true ->
            flags =
              Enum.join(
                ["-connect_all false" | Tartarus.Security.TLSDist.erl_flags(name, dir)],
                " "
              )

            Mix.raise(
              "mix tartarus.node: --tls-certs needs the VM started over TLS distribution, which a task cannot switch on; run:\n" <>
                ~s(ELIXIR_ERL_OPTIONS="#{flags}" mix tartarus.node #{Enum.join(argv, " ")})
            )
        end
    end
  end

  defp start_dashboard(opts) do
    bind =
      case :inet.parse_address(String.to_charlist(opts[:dashboard_bind])) do
        {:ok, ip} ->
          ip

        _ ->
          Mix.raise(
            "mix tartarus.node: --dashboard-bind expects an IP address, got: #{opts[:dashboard_bind]}"
          )
      end

    hosts =
      (opts[:dashboard_hosts] || "") |> String.split(",", trim: true) |> Enum.map(&String.trim/1)

    dash_opts =
      [port: opts[:dashboard], bind: bind, hosts: hosts] ++
        if(opts[:dashboard_token_file], do: [token_file: opts[:dashboard_token_file]], else: [])

    case TartarusDashboard.start(dash_opts) do
      {:ok, dash} ->
        Mix.shell().info(TartarusDashboard.banner(dash))

      {:error, reason} ->
        Mix.raise("mix tartarus.node: cannot start the dashboard: #{inspect(reason)}")
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
