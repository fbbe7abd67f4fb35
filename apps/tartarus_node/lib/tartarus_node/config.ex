defmodule TartarusNode.Config do
  @moduledoc """
  The node's configuration file: read, checked, and turned into what the release needs.

  The file (default `/etc/tartarus/node.exs`, or the path in `TARTARUS_CONFIG`) holds one
  Elixir keyword list (it is evaluated, as `config/runtime.exs` is: keep it owned by root):

      [
        node: "tartarus@198.18.0.1",          # long name: name@address or name@host.domain
        host: "h1",                           # the Tartarus host's name (default: the node's name part)
        tls: [dir: "/etc/tartarus/certs"],    # TLS distribution: <node>.pem, <node>.key, ca.pem
        cookie: "secret",                     # required without tls:
        net_ticktime: 60,
        dist_port: 9100,                      # listen on this port only (default: any, via epmd)
        neighbours: [h2: "tartarus@198.18.0.2"],
        plugins: [
          temp: {:sensor, unit: "°C"},
          io: {Tartarus.Plugin.GPIO, pins: [led: {17, :output}, button: {27, :input}]},
          beacon: {:ble, "/dev/ttyAMA0"},
          tty: {:serial, "/dev/ttyUSB0", speed: 115_200}
        ],
        data_dir: "/var/lib/tartarus",
        durable: false,
        trusted: "/etc/tartarus/trusted",     # issuers' .pub keys: admit only agents they signed
        keys: "/etc/tartarus/keys",           # this host's issuer key pair (issuer.key, issuer.pub)
        dashboard: [port: 4000, bind: "0.0.0.0", hosts: ["pi.local"]],
        services: [{TartarusLats.Device, node: :hall}]
      ]

  Only `node` is required (and `cookie` or `tls`). `tls:` takes `dir:` and/or `cert:`,
  `key:`, `ca:` (files; each defaults to its place in `dir`: `<node>.pem`, `<node>.key`,
  `ca.pem`, as `mix tartarus.gen.certs --nodes <node>` names them). Plugins are `name:
  {module, opts}` or the shorthands `{:sensor, opts}` (`Tartarus.Plugin.SimSensor`, a
  sine-like signal unless `signal:` is given), `{:serial, device}` / `{:serial, device, opts}`
  (`Tartarus.Plugin.Serial`) and `{:ble, device}` / `{:ble, device, opts}` (the BLE receiver
  an application of the release provides: LATS's HM-10 in this umbrella), all parsed by
  `Tartarus.Plugin.Shorthand.parse/3`, as `mix tartarus.node` parses its flags. A serial or
  BLE device that does not exist is refused (`hotplug: true` in its options waits for it
  instead), and so is a GPIO plugin with no GPIO backend (`Tartarus.Plugin.GPIO.check/1`).

  `services:` are processes started once the host runs, each `{module, opts}`: the node
  calls `module.start_link(opts ++ [host: host])` under its supervisor (LATS's
  `TartarusLats.Device` drives the node's database agent every second, so query agents find
  what it saw). A module that is not in the release is refused at the check.

  Everything wrong with the file is one line, `error_line/2`:

      tartarus: bad configuration /etc/tartarus/node.exs: cookie: required without tls:

  `read/1` and `check/1` are pure (but for reading files and checking they exist);
  `TartarusNode.EnvSh.main/0` is what the release's `env.sh` runs before the VM boots.
  """

  @typedoc "A checked configuration."
  @type t :: %{
          node: String.t(),
          distribution: :name | :sname,
          host: atom(),
          cookie: String.t(),
          tls: nil | %{cert: Path.t(), key: Path.t(), ca: Path.t(), operator: String.t()},
          net_ticktime: pos_integer(),
          dist_port: nil | pos_integer(),
          neighbours: [{atom(), atom()}],
          plugins: keyword(),
          data_dir: nil | Path.t(),
          durable: boolean(),
          trusted: nil | Path.t(),
          keys: nil | Path.t(),
          dashboard: nil | keyword(),
          services: [{module(), keyword()}]
        }

  @keys [
    :node,
    :host,
    :cookie,
    :tls,
    :net_ticktime,
    :dist_port,
    :neighbours,
    :plugins,
    :data_dir,
    :durable,
    :trusted,
    :keys,
    :dashboard,
    :services
  ]

  @default_path "/etc/tartarus/node.exs"

  @doc "The configuration file's path: `TARTARUS_CONFIG`, else `/etc/tartarus/node.exs`."
  @spec path() :: Path.t()
  def path, do: System.get_env("TARTARUS_CONFIG") || @default_path

  @doc """
  Reads and checks the file at `path`. `{:error, line}` is `error_line/2`'s one line.
  `opts` are `check/2`'s.

      iex> {:error, line} = TartarusNode.Config.read("/nonexistent/node.exs")
      iex> line
      "tartarus: bad configuration /nonexistent/node.exs: cannot read it (no such file)"
  """
  @spec read(Path.t(), keyword()) :: {:ok, t()} | {:error, String.t()}
  def read(path, opts \\ []) do
    with {:ok, text} <- read_text(path),
         {:ok, term} <- eval(text, path),
         {:ok, config} <- check(term, opts) do
      {:ok, config}
    else
      {:error, what} -> {:error, error_line(path, what)}
    end
  end

  @doc """
  The one line that says what is wrong with the file at `path`.

      iex> TartarusNode.Config.error_line("/etc/tartarus/node.exs", "node: required")
      "tartarus: bad configuration /etc/tartarus/node.exs: node: required"
  """
  @spec error_line(Path.t(), String.t()) :: String.t()
  def error_line(path, what) do
    "tartarus: bad configuration #{path}: " <> String.replace(what, ~r/\s*\n\s*/, " ")
  end

  defp read_text(path) do
    case File.read(path) do
      {:ok, text} -> {:ok, text}
      {:error, :enoent} -> {:error, "cannot read it (no such file)"}
      {:error, reason} -> {:error, "cannot read it (#{:file.format_error(reason)})"}
    end
  end

  defp eval(text, path) do
    {term, _} = Code.eval_string(text, [], file: path)
    {:ok, term}
  rescue
    e in [SyntaxError, TokenMissingError, CompileError] ->
      {:error, "line #{Map.get(e, :line)}: #{Map.get(e, :description) || Exception.message(e)}"}

    e ->
      {:error, "evaluating it raised #{inspect(e.__struct__)}: #{Exception.message(e)}"}
  end

  @doc """
  Checks a configuration term (the file's value) and fills in the defaults.

  Option `devices:` (`:present`, the default, or `:any`): whether a serial or BLE device
  must exist (see `Tartarus.Plugin.Shorthand`); every release command but those that start
  the node (`rpc`, `remote`, `stop`, `pid`, `eval`) reads the file with `:any`, so an
  unplugged adapter does not lock the operator out.

      iex> {:ok, c} = TartarusNode.Config.check(node: "tartarus@198.18.0.1", cookie: "c")
      iex> {c.node, c.distribution, c.host, c.net_ticktime}
      {"tartarus@198.18.0.1", :name, :tartarus, 60}
      iex> TartarusNode.Config.check(node: "tartarus@198.18.0.1")
      {:error, "cookie: required without tls:"}
      iex> TartarusNode.Config.check(node: "n@h", cookie: "c", colour: :red)
      {:error, "unknown key colour: (known: node, host, cookie, tls, net_ticktime, dist_port, neighbours, plugins, data_dir, durable, trusted, keys, dashboard, services)"}
      iex> TartarusNode.Config.check(%{node: "x"})
      {:error, "expected a keyword list, got: %{node: \\"x\\"}"}
  """
  @spec check(term(), keyword()) :: {:ok, t()} | {:error, String.t()}
  def check(term, opts \\ []) do
    with :ok <- keyword(term),
         :ok <- known(term),
         {:ok, node, dist} <- node_name(term[:node]),
         {:ok, host} <- host(term[:host], node),
         {:ok, tls} <- tls(term[:tls], node),
         {:ok, cookie} <- cookie(term[:cookie], tls),
         {:ok, tick} <- pos_int(:net_ticktime, term[:net_ticktime], 60),
         {:ok, port} <- port(term[:dist_port]),
         {:ok, neighbours} <- neighbours(term[:neighbours] || []),
         {:ok, plugins} <- plugins(term[:plugins] || [], Keyword.get(opts, :devices, :present)),
         {:ok, data_dir} <- path_opt(:data_dir, term[:data_dir]),
         :ok <- data_dir_usable(data_dir),
         {:ok, durable} <- durable(term[:durable], data_dir),
         {:ok, trusted} <- dir_opt(:trusted, term[:trusted]),
         {:ok, keys} <- dir_opt(:keys, term[:keys]),
         {:ok, dashboard} <- dashboard(term[:dashboard]),
         {:ok, services} <- services(term[:services] || []) do
      {:ok,
       %{
         node: node,
         distribution: dist,
         host: host,
         cookie: cookie,
         tls: tls,
         net_ticktime: tick,
         dist_port: port,
         neighbours: neighbours,
         plugins: plugins,
         data_dir: data_dir,
         durable: durable,
         trusted: trusted,
         keys: keys,
         dashboard: dashboard,
         services: services
       }}
    end
  end

  defp keyword(term) do
    if is_list(term) and term != [] and Keyword.keyword?(term),
      do: :ok,
      else: {:error, "expected a keyword list, got: #{inspect(term, limit: 5)}"}
  end

  defp known(term) do
    case Enum.find(Keyword.keys(term), &(&1 not in @keys)) do
      nil -> :ok
      key -> {:error, "unknown key #{key}: (known: #{Enum.join(@keys, ", ")})"}
    end
  end

  defp node_name(nil), do: {:error, "node: required (e.g. node: \"tartarus@198.18.0.1\")"}

  defp node_name(name) when is_binary(name) or is_atom(name) do
    name = to_string(name)

    case String.split(name, "@") do
      [n, h] when n != "" and h != "" ->
        if String.match?(n, ~r/^[A-Za-z0-9_-]+$/),
          do: {:ok, name, distribution(h)},
          else: {:error, "node: the name part may hold letters, digits, _ and - only, got: #{name}"}

      _ ->
        {:error, "node: expected name@host, got: #{inspect(name)}"}
    end
  end

  defp node_name(other), do: {:error, "node: expected a string name@host, got: #{inspect(other)}"}

  # Long names when the host part is an address or holds a dot.
  defp distribution(host) do
    if String.contains?(host, ".") or match?({:ok, _}, :inet.parse_address(~c"#{host}")),
      do: :name,
      else: :sname
  end

  defp host(nil, node), do: {:ok, node |> String.split("@") |> hd() |> String.to_atom()}
  defp host(h, _) when is_atom(h) and h not in [nil, true, false], do: {:ok, h}
  defp host(h, _) when is_binary(h) and h != "", do: {:ok, String.to_atom(h)}
  defp host(other, _), do: {:error, "host: expected a name, got: #{inspect(other)}"}

  defp tls(nil, _), do: {:ok, nil}

  defp tls(opts, node) when is_list(opts) do
    dir = opts[:dir]

    with :ok <- only(:tls, opts, [:dir, :cert, :key, :ca, :operator]),
         {:ok, cert} <- tls_file(:cert, opts[:cert], dir, "#{node}.pem"),
         {:ok, key} <- tls_file(:key, opts[:key], dir, "#{node}.key"),
         {:ok, ca} <- tls_file(:ca, opts[:ca], dir, "ca.pem"),
         {:ok, operator} <- operator(opts[:operator]) do
      {:ok, %{cert: cert, key: key, ca: ca, operator: operator}}
    end
  end

  defp tls(other, _),
    do: {:error, "tls: expected [dir: path] or [cert:, key:, ca:], got: #{inspect(other)}"}

  defp operator(nil), do: {:ok, "operator"}

  defp operator(name) when is_binary(name) or (is_atom(name) and name not in [true, false]) do
    if String.match?(to_string(name), ~r/^[A-Za-z0-9_-]+$/),
      do: {:ok, to_string(name)},
      else: {:error, "tls: operator: a certificate's name (letters, digits, _ and -), got: #{inspect(name)}"}
  end

  defp operator(other), do: {:error, "tls: operator: expected a name, got: #{inspect(other)}"}

  defp tls_file(key, nil, nil, _),
    do: {:error, "tls: #{key}: required (or dir: holding the certificates)"}

  defp tls_file(key, nil, dir, name), do: tls_file(key, Path.join(dir, name), nil, nil)

  defp tls_file(key, file, _, _) when is_binary(file) do
    if File.regular?(file),
      do: {:ok, Path.expand(file)},
      else: {:error, "tls: #{key}: no such file #{file}"}
  end

  defp tls_file(key, other, _, _), do: {:error, "tls: #{key}: expected a path, got: #{inspect(other)}"}

  defp only(what, opts, allowed) do
    cond do
      not Keyword.keyword?(opts) ->
        {:error, "#{what}: expected a keyword list, got: #{inspect(opts)}"}

      bad = Enum.find(Keyword.keys(opts), &(&1 not in allowed)) ->
        {:error, "#{what}: unknown key #{bad}: (known: #{Enum.join(allowed, ", ")})"}

      true ->
        :ok
    end
  end

  # Under TLS the cookie is no security (the certificates are), so it has a default.
  defp cookie(nil, nil), do: {:error, "cookie: required without tls:"}
  defp cookie(nil, _tls), do: {:ok, "tartarus"}
  defp cookie(c, _) when (is_binary(c) and c != "") or (is_atom(c) and c != nil), do: {:ok, to_string(c)}
  defp cookie(other, _), do: {:error, "cookie: expected a string, got: #{inspect(other)}"}

  defp pos_int(_key, nil, default), do: {:ok, default}
  defp pos_int(_key, n, _) when is_integer(n) and n > 0, do: {:ok, n}
  defp pos_int(key, other, _), do: {:error, "#{key}: expected a positive integer, got: #{inspect(other)}"}

  defp port(nil), do: {:ok, nil}
  defp port(p) when is_integer(p) and p in 1..65_535, do: {:ok, p}
  defp port(other), do: {:error, "dist_port: expected a port number, got: #{inspect(other)}"}

  defp neighbours(list) when is_list(list) do
    Enum.reduce_while(list, {:ok, []}, fn
      {h, n}, {:ok, acc} when (is_atom(h) or is_binary(h)) and (is_atom(n) or is_binary(n)) ->
        if String.contains?(to_string(n), "@"),
          do: {:cont, {:ok, acc ++ [{to_atom(h), to_atom(n)}]}},
          else: {:halt, {:error, "neighbours: #{h}: expected a node name@host, got: #{inspect(n)}"}}

      other, _ ->
        {:halt, {:error, "neighbours: expected host: \"name@host\" items, got: #{inspect(other)}"}}
    end)
  end

  defp neighbours(other),
    do: {:error, "neighbours: expected a keyword list host: \"name@host\", got: #{inspect(other)}"}

  defp to_atom(x) when is_atom(x), do: x
  defp to_atom(x), do: String.to_atom(x)

  defp plugins(list, devices) when is_list(list) do
    Enum.reduce_while(list, {:ok, []}, fn
      {name, spec}, {:ok, acc} when is_atom(name) ->
        case plugin(name, spec, devices) do
          {:ok, s} -> {:cont, {:ok, acc ++ [{name, s}]}}
          {:error, _} = e -> {:halt, e}
        end

      other, _ ->
        {:halt, {:error, "plugins: expected name: spec items, got: #{inspect(other)}"}}
    end)
  end

  defp plugins(other, _), do: {:error, "plugins: expected a keyword list, got: #{inspect(other)}"}

  # One function for every shorthand, shared with `mix tartarus.node`; here a device that is
  # not there is refused unless the spec says hotplug: true.
  defp plugin(name, spec, devices) do
    case Tartarus.Plugin.Shorthand.parse(name, spec, devices: devices) do
      {:ok, spec} -> {:ok, spec}
      {:error, line} -> {:error, "plugins: " <> line}
    end
  end

  defp path_opt(_key, nil), do: {:ok, nil}
  defp path_opt(_key, p) when is_binary(p) and p != "", do: {:ok, Path.expand(p)}
  defp path_opt(key, other), do: {:error, "#{key}: expected a path, got: #{inspect(other)}"}

  defp dir_opt(key, value) do
    case path_opt(key, value) do
      {:ok, nil} -> {:ok, nil}
      {:ok, p} -> if File.dir?(p), do: {:ok, p}, else: {:error, "#{key}: no such directory #{p}"}
      error -> error
    end
  end

  # The data directory must be a directory the node can write, or one it can make: the
  # nearest existing ancestor is then a directory it can write.
  defp data_dir_usable(nil), do: :ok

  defp data_dir_usable(dir) do
    {existing, _} =
      Enum.reduce_while(Stream.iterate(dir, &Path.dirname/1), {dir, nil}, fn p, _ ->
        if File.exists?(p) or p == "/", do: {:halt, {p, p}}, else: {:cont, {p, p}}
      end)

    what = if existing == dir, do: dir, else: "#{existing} (to make #{dir} in)"

    case File.stat(existing) do
      {:ok, %File.Stat{type: :directory, access: access}} when access in [:write, :read_write] ->
        :ok

      {:ok, %File.Stat{type: :directory}} ->
        {:error, "data_dir: cannot write #{what} (permission denied)"}

      {:ok, %File.Stat{}} ->
        {:error, "data_dir: #{existing} is not a directory"}

      {:error, reason} ->
        {:error, "data_dir: cannot use #{what} (#{:file.format_error(reason)})"}
    end
  end

  defp durable(nil, _), do: {:ok, false}
  defp durable(false, _), do: {:ok, false}
  defp durable(true, nil), do: {:error, "durable: true needs data_dir:"}
  defp durable(true, _), do: {:ok, true}
  defp durable(other, _), do: {:error, "durable: expected true or false, got: #{inspect(other)}"}

  @doc """
  The dashboard this node's applications provide (`tartarus_dashboard:` in an application's
  environment, see `Tartarus.Provides`: the dashboard app's `TartarusDashboard`), or the
  one line saying there is none: a release built with `TARTARUS_RELEASE_DASHBOARD=false`
  is without it.
  """
  @spec dashboard_module() :: {:ok, module()} | {:error, String.t()}
  def dashboard_module do
    case Tartarus.Provides.find(:tartarus_dashboard) do
      [{_app, module} | _] when is_atom(module) ->
        if Code.ensure_loaded?(module) and function_exported?(module, :start, 1),
          do: {:ok, module},
          else: {:error, "dashboard: #{inspect(module)} is not in this node's code"}

      _ ->
        {:error,
         "dashboard: this node has no dashboard (this release was built with " <>
           "TARTARUS_RELEASE_DASHBOARD=false: build it without that to have one)"}
    end
  end

  defp services(list) when is_list(list) do
    Enum.reduce_while(list, {:ok, []}, fn
      {module, opts}, {:ok, acc} when is_atom(module) and is_list(opts) ->
        if Code.ensure_loaded?(module) and function_exported?(module, :start_link, 1),
          do: {:cont, {:ok, acc ++ [{module, opts}]}},
          else:
            {:halt,
             {:error, "services: #{inspect(module)} is not in this node's code (or has no start_link/1)"}}

      other, _ ->
        {:halt, {:error, "services: expected {module, opts} items, got: #{inspect(other)}"}}
    end)
  end

  defp services(other),
    do: {:error, "services: expected a list of {module, opts}, got: #{inspect(other)}"}

  defp dashboard(nil), do: {:ok, nil}

  defp dashboard(opts) when is_list(opts) do
    with :ok <- only(:dashboard, opts, [:port, :bind, :hosts, :token_file]),
         {:ok, _module} <- dashboard_module(),
         true <- is_integer(opts[:port]) and opts[:port] in 0..65_535,
         {:ok, bind} <- :inet.parse_address(~c"#{opts[:bind] || "127.0.0.1"}") do
      {:ok,
       [port: opts[:port], bind: bind, hosts: opts[:hosts] || []] ++
         if(opts[:token_file], do: [token_file: opts[:token_file]], else: [])}
    else
      {:error, _} = e when is_binary(elem(e, 1)) -> e
      false -> {:error, "dashboard: port: expected a port number, got: #{inspect(opts[:port])}"}
      {:error, :einval} -> {:error, "dashboard: bind: expected an IP address, got: #{inspect(opts[:bind])}"}
    end
  end

  defp dashboard(other), do: {:error, "dashboard: expected [port: n, ...], got: #{inspect(other)}"}

  @doc """
  The options `Tartarus.start_host/2` gets: plugins, persistence and security (neighbours
  are linked later, by `TartarusNode.Boot`, once they answer).
  """
  @spec host_options(t()) :: keyword()
  def host_options(c) do
    security =
      Enum.reject(
        [
          trust: c.trusted && trust!(c.trusted),
          keys: c.keys && Tartarus.Security.Keys.load!(c.keys)
        ],
        fn {_, v} -> v in [nil, false] end
      )

    [plugins: c.plugins] ++
      if(c.data_dir, do: [data_dir: c.data_dir, durable: c.durable], else: []) ++
      if(security == [], do: [], else: [security: security])
  end

  defp trust!(dir) do
    {:ok, trust} = Tartarus.Security.TrustList.from_dir(dir)
    trust
  end

  @doc """
  The `erl` flags the node boots with (besides its name and cookie): the tick time, the
  listening port, and TLS distribution with `optfile` as `-ssl_dist_optfile`. With role
  `:client` (the release's `rpc`, `remote`, `stop`, `pid`: a VM that only dials the node)
  the listening port is left out, since the node holds it.

      iex> {:ok, c} = TartarusNode.Config.check(node: "a@198.18.0.1", cookie: "x", net_ticktime: 8, dist_port: 9100)
      iex> TartarusNode.Config.erl_flags(c, "/tmp/ssl_dist.conf")
      ["-connect_all", "false", "-kernel", "net_ticktime", "8", "-kernel", "inet_dist_listen_min", "9100", "-kernel", "inet_dist_listen_max", "9100"]
  """
  @spec erl_flags(t(), Path.t(), :node | :client) :: [String.t()]
  def erl_flags(c, optfile, role \\ :node) do
    ["-connect_all", "false", "-kernel", "net_ticktime", "#{c.net_ticktime}"] ++
      if(c.dist_port && role == :node,
        do: ["-kernel", "inet_dist_listen_min", "#{c.dist_port}"] ++
              ["-kernel", "inet_dist_listen_max", "#{c.dist_port}"],
        else: []
      ) ++
      if(c.tls, do: ["-proto_dist", "tartarus_tls", "-ssl_dist_optfile", optfile], else: [])
  end

  @doc """
  The TLS distribution option file's terms for `c.tls` (as `Tartarus.Security.TLSDist`
  writes them, with this configuration's files).
  """
  @spec optfile_terms(t()) :: [{:server | :client, keyword()}]
  def optfile_terms(%{tls: %{cert: cert, key: key, ca: ca}}) do
    common = [
      certfile: ~c"#{cert}",
      keyfile: ~c"#{key}",
      cacertfile: ~c"#{ca}",
      verify: :verify_peer,
      secure_renegotiate: true
    ]

    [server: common ++ [fail_if_no_peer_cert: true], client: common]
  end

  @doc """
  The shell assignments `env.sh` evaluates before the VM boots: `RELEASE_DISTRIBUTION`,
  `RELEASE_NODE`, `RELEASE_COOKIE` and `TARTARUS_ERL_FLAGS`.

      iex> {:ok, c} = TartarusNode.Config.check(node: "a@198.18.0.1", cookie: "it's")
      iex> TartarusNode.Config.shell(c, "/tmp/o.conf")
      "RELEASE_DISTRIBUTION=name\\nRELEASE_NODE='a@198.18.0.1'\\nRELEASE_COOKIE='it'\\\\''s'\\nTARTARUS_ERL_FLAGS='-connect_all false -kernel net_ticktime 60'\\n"
  """
  @spec shell(t(), Path.t(), :node | :client) :: String.t()
  def shell(c, optfile, role \\ :node) do
    shell_assignments(
      RELEASE_DISTRIBUTION: Atom.to_string(c.distribution),
      RELEASE_NODE: c.node,
      RELEASE_COOKIE: c.cookie,
      TARTARUS_ERL_FLAGS: Enum.join(erl_flags(c, optfile, role), " ")
    )
  end

  @doc false
  # `NAME='value'` lines, quoted for sh (the distribution's name is left bare).
  @spec shell_assignments(keyword(String.t())) :: String.t()
  def shell_assignments(pairs) do
    Enum.map_join(pairs, fn
      {:RELEASE_DISTRIBUTION, v} -> "RELEASE_DISTRIBUTION=#{v}\n"
      {k, v} -> "#{k}=#{quote_sh(v)}\n"
    end)
  end

  defp quote_sh(s), do: "'" <> String.replace(s, "'", "'\\''") <> "'"
end
