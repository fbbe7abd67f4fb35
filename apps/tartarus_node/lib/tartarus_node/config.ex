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

  # Bounds. A node's file is a few hundred bytes: one of more than @max_bytes is refused
  # before it is evaluated, since evaluating Elixir takes time that grows faster than the
  # text (here: 160 KB of neighbours parsed in 0.07 s, 660 KB in 0.45 s, 6.9 MB in 24 s);
  # 256 KiB holds about 8,000 neighbours. Evaluation that has not ended after @eval_ms is
  # stopped. The tick time: OTP ticks every net_ticktime/4 s, with a timer that must fit in
  # 2^32 ms; an hour is far beyond any use.
  @max_bytes 262_144
  @eval_ms 30_000
  @ticktime 1..3600
  @port 1..65_535
  # A node name's parts, as they reach the VM's command line: a name of letters, digits, _
  # and -; a host of letters, digits, _, . and - (a host name or an IPv4 address), or an
  # IPv6 address. At most 255 bytes in all (an atom's limit).
  @name_part ~r/^[A-Za-z0-9_-]+$/
  @host_part ~r/^[A-Za-z0-9_]([A-Za-z0-9_.-]*[A-Za-z0-9_])?$/
  # Atoms: 255 characters at most.
  @max_atom 255
  # What an error line shows of a value.
  @show [limit: 8, printable_limit: 120]

  @doc "The configuration file's path: `TARTARUS_CONFIG`, else `/etc/tartarus/node.exs`."
  @spec path() :: Path.t()
  def path, do: System.get_env("TARTARUS_CONFIG") || @default_path

  @doc """
  Reads and checks the file at `path`. `{:error, line}` is `error_line/2`'s one line.
  `opts` are `check/2`'s.

  Never raises: a file over 256 KiB is refused before it is evaluated; evaluating it runs in a
  process of its own (its standard output goes to standard error, so a stray `IO.puts` does
  not reach `env.sh`), and whatever it raises, throws or exits with, or 30 s without an
  answer, is the one line. The file is Elixir code run with the release's rights: it must be
  trusted as the release itself is.

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
  The one line that says what is wrong with the file at `path` (at most 2,000 characters of
  it).

      iex> TartarusNode.Config.error_line("/etc/tartarus/node.exs", "node: required")
      "tartarus: bad configuration /etc/tartarus/node.exs: node: required"
  """
  @spec error_line(Path.t(), String.t()) :: String.t()
  def error_line(path, what) do
    what = String.replace(what, ~r/\s*[\r\n]\s*/, " ")
    what = if String.length(what) > 2_000, do: String.slice(what, 0, 2_000) <> "...", else: what
    "tartarus: bad configuration #{path}: " <> what
  end

  # At most @max_bytes + 1 bytes are read, whatever the path is (a device, a pipe).
  defp read_text(path) do
    case File.open(path, [:read, :binary]) do
      {:ok, io} ->
        text = IO.binread(io, @max_bytes + 1)
        File.close(io)
        text(text)

      {:error, :enoent} ->
        {:error, "cannot read it (no such file)"}

      {:error, reason} ->
        {:error, "cannot read it (#{:file.format_error(reason)})"}
    end
  end

  defp text(:eof), do: {:ok, ""}

  defp text(text) when is_binary(text) and byte_size(text) > @max_bytes,
    do:
      {:error,
       "it has more than #{@max_bytes} bytes (256 KiB), the most a node's file may have " <>
         "(it is evaluated as Elixir code, in time that grows faster than its size)"}

  defp text(text) when is_binary(text), do: {:ok, text}
  defp text({:error, reason}), do: {:error, "cannot read it (#{inspect(reason)})"}

  # In a process of its own: a linked process the file starts and that dies, or an exit, is
  # its end, not the caller's; what it prints goes to standard error.
  defp eval(text, path) do
    tag = make_ref()

    {pid, ref} =
      spawn_monitor(fn ->
        Process.group_leader(self(), Process.whereis(:standard_error) || Process.group_leader())
        exit({tag, eval_here(text, path)})
      end)

    timer = Tartarus.Clock.send_after(self(), {__MODULE__, :eval_timeout, ref}, @eval_ms)

    result =
      receive do
        {:DOWN, ^ref, :process, ^pid, {^tag, result}} ->
          result

        {:DOWN, ^ref, :process, ^pid, reason} ->
          {:error, "evaluating it stopped with #{show(reason)}"}

        {__MODULE__, :eval_timeout, ^ref} ->
          Process.demonitor(ref, [:flush])
          Process.exit(pid, :kill)
          {:error, "evaluating it took more than #{div(@eval_ms, 1000)} s"}
      end

    # (Should it fire as the answer comes, the stray message is harmless: it names this ref.)
    Tartarus.Clock.cancel_timer(timer)
    result
  end

  defp eval_here(text, path) do
    {term, _} = Code.eval_string(text, [], file: path)
    {:ok, term}
  rescue
    e in [SyntaxError, TokenMissingError, CompileError] ->
      {:error, "line #{Map.get(e, :line)}: #{Map.get(e, :description) || message(e)}"}

    e ->
      {:error, "evaluating it raised #{inspect(e.__struct__)}: #{message(e)}"}
  catch
    :throw, value -> {:error, "evaluating it threw #{show(value)}"}
    :exit, reason -> {:error, "evaluating it exited with #{show(reason)}"}
  end

  # An exception's message, even when its message/1 raises.
  defp message(e) do
    Exception.message(e)
  rescue
    _ -> show(e)
  end

  defp show(term), do: inspect(term, @show)

  @doc """
  Checks a configuration term (the file's value) and fills in the defaults.

  Every value is checked for its type and range before anything uses it, and `check/2`
  never raises (a plugin's own `check/1` that raises is one line too). Names are checked as
  names: `node:` and each neighbour's are `name@host` (the name of letters, digits, `_` and
  `-`; the host a host name, an IPv4 or an IPv6 address), at most 255 bytes, so nothing but
  a name reaches the VM's command line; a host's name (`host:`, a neighbour's key) is
  letters, digits, `_`, `.` and `-`. `net_ticktime` is 1..3600 s, ports 1..65535 (the
  dashboard's 0..65535, 0 for any). `keys:` must hold a key pair that loads
  (`Tartarus.Security.Keys.load/2`), `trusted:` `.pub` files that load, and `data_dir:` is
  made if missing and must take a file (a probe file is written and removed), as the host
  will need. Time is linear in the term's size.

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
      iex> TartarusNode.Config.check(node: "n@h", cookie: "c", net_ticktime: 10 ** 40)
      {:error, "net_ticktime: expected an integer in 1..3600 (seconds), got: 10000000000000000000000000000000000000000"}
  """
  @spec check(term(), keyword()) :: {:ok, t()} | {:error, String.t()}
  def check(term, opts \\ []) do
    check_term(term, opts)
  rescue
    e -> {:error, "checking it raised #{inspect(e.__struct__)}: #{message(e)}"}
  catch
    kind, reason -> {:error, "checking it failed (#{kind}): #{show(reason)}"}
  end

  defp check_term(term, opts) do
    with :ok <- keyword(term),
         :ok <- known(term),
         :ok <- once("", Keyword.keys(term)),
         {:ok, node, dist} <- node_name(:node, term[:node]),
         {:ok, host} <- host(term[:host], node),
         {:ok, tls} <- tls(term[:tls], node),
         {:ok, cookie} <- cookie(term[:cookie], tls),
         {:ok, tick} <- int_in(:net_ticktime, term[:net_ticktime], 60, @ticktime, " (seconds)"),
         {:ok, port} <- int_in(:dist_port, term[:dist_port], nil, @port, " (a port)"),
         {:ok, neighbours} <- neighbours(term[:neighbours] || []),
         {:ok, plugins} <- plugins(term[:plugins] || [], Keyword.get(opts, :devices, :present)),
         {:ok, data_dir} <- path_opt(:data_dir, term[:data_dir]),
         :ok <- data_dir_usable(data_dir),
         {:ok, durable} <- durable(term[:durable], data_dir),
         {:ok, trusted} <- dir_opt(:trusted, term[:trusted]),
         {:ok, _} <- load_trust(trusted),
         {:ok, keys} <- dir_opt(:keys, term[:keys]),
         {:ok, _} <- load_keys(keys),
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
      else: {:error, "expected a keyword list, got: #{show(term)}"}
  end

  defp known(term) do
    case Enum.find(Keyword.keys(term), &(&1 not in @keys)) do
      nil -> :ok
      key -> {:error, "unknown key #{show_key(key)}: (known: #{Enum.join(@keys, ", ")})"}
    end
  end

  defp show_key(key), do: key |> Atom.to_string() |> String.slice(0, 64)

  # Each name once (keys of the file, of plugins, of neighbours), in linear time.
  defp once(prefix, names) do
    Enum.reduce_while(names, MapSet.new(), fn name, seen ->
      if MapSet.member?(seen, name),
        do: {:halt, {:error, "#{prefix}#{show_key(name)}: given twice"}},
        else: {:cont, MapSet.put(seen, name)}
    end)
    |> case do
      {:error, _} = e -> e
      _ -> :ok
    end
  end

  @doc """
  Whether `name` (a string or an atom) is a node name as the release puts it on the VM's
  command line: `{:ok, name}` or `{:error, why}`.

      iex> TartarusNode.Config.node_name_ok("tartarus@pi1.local")
      {:ok, "tartarus@pi1.local"}
      iex> TartarusNode.Config.node_name_ok("t@127.0.0.1 --eval System.halt(7)")
      {:error, "expected name@host (name: letters, digits, _ and -; host: a host name, an IPv4 or an IPv6 address), got: \\"t@127.0.0.1 --eval System.halt(7)\\""}
  """
  @spec node_name_ok(term()) :: {:ok, String.t()} | {:error, String.t()}
  def node_name_ok(name)
      when (is_atom(name) and name not in [nil, true, false]) or is_binary(name) do
    name = to_string(name)

    valid? =
      byte_size(name) <= @max_atom and
        case String.split(name, "@") do
          [n, h] -> String.match?(n, @name_part) and host_part?(h)
          _ -> false
        end

    if valid?,
      do: {:ok, name},
      else:
        {:error,
         "expected name@host (name: letters, digits, _ and -; host: a host name, an IPv4 or " <>
           "an IPv6 address), got: #{show(name)}"}
  end

  def node_name_ok(other), do: {:error, "expected a string name@host, got: #{show(other)}"}

  defp host_part?(h) do
    String.match?(h, @host_part) or
      (String.contains?(h, ":") and String.match?(h, ~r/^[0-9A-Fa-f:.]+$/) and
         match?({:ok, _}, :inet.parse_ipv6strict_address(String.to_charlist(h))))
  end

  defp node_name(_key, nil), do: {:error, "node: required (e.g. node: \"tartarus@198.18.0.1\")"}

  defp node_name(key, name) do
    case node_name_ok(name) do
      {:ok, name} -> {:ok, name, distribution(name |> String.split("@") |> List.last())}
      {:error, why} -> {:error, "#{key}: #{why}"}
    end
  end

  # Long names when the host part is an address or holds a dot.
  defp distribution(host) do
    if String.contains?(host, ".") or match?({:ok, _}, :inet.parse_address(~c"#{host}")),
      do: :name,
      else: :sname
  end

  defp host(nil, node), do: {:ok, node |> String.split("@") |> hd() |> String.to_atom()}

  defp host(h, _) do
    case host_name(h) do
      {:ok, h} -> {:ok, h}
      {:error, why} -> {:error, "host: #{why}"}
    end
  end

  # A host's name: an atom or a string of letters, digits, _, . and -, at most 255 of them.
  defp host_name(h) when is_atom(h) and h not in [nil, true, false],
    do: host_name(Atom.to_string(h))

  defp host_name(h) when is_binary(h) do
    if byte_size(h) in 1..@max_atom and String.match?(h, ~r/^[A-Za-z0-9_.-]+$/),
      do: {:ok, String.to_atom(h)},
      else:
        {:error, "expected a name of letters, digits, _, . and - (at most 255), got: #{show(h)}"}
  end

  defp host_name(other), do: {:error, "expected a name, got: #{show(other)}"}

  defp tls(nil, _), do: {:ok, nil}

  defp tls(opts, node) when is_list(opts) do
    with :ok <- only(:tls, opts, [:dir, :cert, :key, :ca, :operator]),
         {:ok, dir} <- path_opt(:"tls: dir", opts[:dir]),
         {:ok, cert} <- tls_file(:cert, opts[:cert], dir, "#{node}.pem"),
         {:ok, key} <- tls_file(:key, opts[:key], dir, "#{node}.key"),
         {:ok, ca} <- tls_file(:ca, opts[:ca], dir, "ca.pem"),
         {:ok, operator} <- operator(opts[:operator]) do
      {:ok, %{cert: cert, key: key, ca: ca, operator: operator}}
    end
  end

  defp tls(other, _),
    do: {:error, "tls: expected [dir: path] or [cert:, key:, ca:], got: #{show(other)}"}

  defp operator(nil), do: {:ok, "operator"}

  defp operator(name) when is_binary(name) or (is_atom(name) and name not in [true, false]) do
    if byte_size(to_string(name)) <= 64 and String.match?(to_string(name), @name_part),
      do: {:ok, to_string(name)},
      else:
        {:error,
         "tls: operator: a certificate's name (letters, digits, _ and -, at most 64), got: #{show(name)}"}
  end

  defp operator(other), do: {:error, "tls: operator: expected a name, got: #{show(other)}"}

  defp tls_file(key, nil, nil, _),
    do: {:error, "tls: #{key}: required (or dir: holding the certificates)"}

  defp tls_file(key, nil, dir, name), do: tls_file(key, Path.join(dir, name), nil, nil)

  defp tls_file(key, file, _, _), do: existing(:"tls: #{key}", file, :file)

  defp only(what, opts, allowed) do
    cond do
      not Keyword.keyword?(opts) ->
        {:error, "#{what}: expected a keyword list, got: #{show(opts)}"}

      bad = Enum.find(Keyword.keys(opts), &(&1 not in allowed)) ->
        {:error, "#{what}: unknown key #{show_key(bad)}: (known: #{Enum.join(allowed, ", ")})"}

      true ->
        once("#{what}: ", Keyword.keys(opts))
    end
  end

  # Under TLS the cookie is no security (the certificates are), so it has a default. A cookie
  # is an atom on the VM's command line: 1 to 255 printable ASCII characters, no spaces.
  defp cookie(nil, nil), do: {:error, "cookie: required without tls:"}
  defp cookie(nil, _tls), do: {:ok, "tartarus"}

  defp cookie(c, _)
       when (is_binary(c) and c != "") or (is_atom(c) and c not in [nil, true, false]) do
    c = to_string(c)

    if byte_size(c) <= @max_atom and String.match?(c, ~r/^[\x21-\x7e]+$/),
      do: {:ok, c},
      else:
        {:error,
         "cookie: expected 1 to 255 printable ASCII characters without spaces, got: #{show(c)}"}
  end

  defp cookie(other, _), do: {:error, "cookie: expected a string, got: #{show(other)}"}

  defp int_in(_key, nil, default, _range, _unit), do: {:ok, default}

  defp int_in(key, n, _, first..last = range, unit) do
    if is_integer(n) and n in range,
      do: {:ok, n},
      else: {:error, "#{key}: expected an integer in #{first}..#{last}#{unit}, got: #{show(n)}"}
  end

  # Linear: each item checked once, the list built reversed and turned once.
  defp neighbours(list) when is_list(list) do
    Enum.reduce_while(list, {:ok, []}, fn
      {h, n}, {:ok, acc} ->
        with {:ok, h} <- host_name(h),
             {:ok, n} <- node_name_ok(n) do
          {:cont, {:ok, [{h, String.to_atom(n)} | acc]}}
        else
          {:error, why} -> {:halt, {:error, "neighbours: #{show_neighbour(h)}: #{why}"}}
        end

      other, _ ->
        {:halt, {:error, "neighbours: expected host: \"name@host\" items, got: #{show(other)}"}}
    end)
    |> reversed()
  end

  defp neighbours(other),
    do: {:error, "neighbours: expected a keyword list host: \"name@host\", got: #{show(other)}"}

  defp show_neighbour(h) when is_atom(h), do: show_key(h)
  defp show_neighbour(h), do: show(h)

  defp reversed({:ok, list}), do: {:ok, Enum.reverse(list)}
  defp reversed(error), do: error

  defp plugins(list, devices) when is_list(list) do
    Enum.reduce_while(list, {:ok, [], MapSet.new()}, fn
      {name, spec}, {:ok, acc, seen} when is_atom(name) ->
        cond do
          MapSet.member?(seen, name) ->
            {:halt, {:error, "plugins: #{show_key(name)}: given twice"}}

          true ->
            case plugin(name, spec, devices) do
              {:ok, s} -> {:cont, {:ok, [{name, s} | acc], MapSet.put(seen, name)}}
              {:error, _} = e -> {:halt, e}
            end
        end

      other, _ ->
        {:halt, {:error, "plugins: expected name: spec items, got: #{show(other)}"}}
    end)
    |> case do
      {:ok, acc, _} -> {:ok, Enum.reverse(acc)}
      error -> error
    end
  end

  defp plugins(other, _), do: {:error, "plugins: expected a keyword list, got: #{show(other)}"}

  # One function for every shorthand, shared with `mix tartarus.node`; here a device that is
  # not there is refused unless the spec says hotplug: true. A plugin module's check/1 is
  # its code: what it raises is one line too.
  defp plugin(name, spec, devices) do
    case Tartarus.Plugin.Shorthand.parse(name, spec, devices: devices) do
      {:ok, spec} -> {:ok, spec}
      {:error, line} -> {:error, "plugins: " <> line}
    end
  rescue
    e ->
      {:error,
       "plugins: #{show_key(name)}: checking it raised #{inspect(e.__struct__)}: #{message(e)}"}
  catch
    kind, reason ->
      {:error, "plugins: #{show_key(name)}: checking it failed (#{kind}): #{show(reason)}"}
  end

  # A path: a non-empty UTF-8 string without NUL bytes, at most 4096 bytes (PATH_MAX).
  defp path_opt(_key, nil), do: {:ok, nil}

  defp path_opt(key, p) when is_binary(p) do
    if p != "" and byte_size(p) <= 4096 and String.valid?(p) and not String.contains?(p, <<0>>),
      do: {:ok, Path.expand(p)},
      else: {:error, "#{key}: expected a path, got: #{show(p)}"}
  end

  defp path_opt(key, other), do: {:error, "#{key}: expected a path, got: #{show(other)}"}

  defp dir_opt(key, value), do: existing(key, value, :dir)

  # An optional path that must name an existing directory or regular file.
  defp existing(key, value, kind) do
    case path_opt(key, value) do
      {:ok, nil} ->
        {:ok, nil}

      {:ok, p} ->
        cond do
          kind == :dir and File.dir?(p) -> {:ok, p}
          kind == :file and File.regular?(p) -> {:ok, p}
          kind == :dir -> {:error, "#{key}: no such directory #{p}"}
          true -> {:error, "#{key}: no such file #{p}"}
        end

      error ->
        error
    end
  end

  # The data directory must be a directory the node can write, or one it can make: the
  # nearest existing ancestor is then a directory it can write. Then, as the host will, it
  # is made and a file is written in it (a probe, removed): a read-only file system or a
  # name too long is found here, not at boot.
  defp data_dir_usable(nil), do: :ok

  defp data_dir_usable(dir) do
    {existing, _} =
      Enum.reduce_while(Stream.iterate(dir, &Path.dirname/1), {dir, nil}, fn p, _ ->
        if File.exists?(p) or p == "/", do: {:halt, {p, p}}, else: {:cont, {p, p}}
      end)

    what = if existing == dir, do: dir, else: "#{existing} (to make #{dir} in)"

    case File.stat(existing) do
      {:ok, %File.Stat{type: :directory, access: access}} when access in [:write, :read_write] ->
        data_dir_probe(dir)

      {:ok, %File.Stat{type: :directory}} ->
        {:error, "data_dir: cannot write #{what} (permission denied)"}

      {:ok, %File.Stat{}} ->
        {:error, "data_dir: #{existing} is not a directory"}

      {:error, reason} ->
        {:error, "data_dir: cannot use #{what} (#{:file.format_error(reason)})"}
    end
  end

  defp data_dir_probe(dir) do
    probe = Path.join(dir, ".tartarus-check-#{System.unique_integer([:positive])}")

    with {:mkdir, :ok} <- {:mkdir, File.mkdir_p(dir)},
         {:write, :ok} <- {:write, File.write(probe, "")} do
      _ = File.rm(probe)
      :ok
    else
      {:mkdir, {:error, reason}} ->
        {:error, "data_dir: cannot make #{dir} (#{:file.format_error(reason)})"}

      {:write, {:error, reason}} ->
        {:error, "data_dir: cannot write a file in #{dir} (#{:file.format_error(reason)})"}
    end
  end

  defp durable(nil, _), do: {:ok, false}
  defp durable(false, _), do: {:ok, false}
  defp durable(true, nil), do: {:error, "durable: true needs data_dir:"}
  defp durable(true, _), do: {:ok, true}
  defp durable(other, _), do: {:error, "durable: expected true or false, got: #{show(other)}"}

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
        cond do
          not Keyword.keyword?(opts) ->
            {:halt,
             {:error,
              "services: #{inspect(module)}: expected a keyword list of options, got: #{show(opts)}"}}

          Code.ensure_loaded?(module) and function_exported?(module, :start_link, 1) ->
            {:cont, {:ok, [{module, opts} | acc]}}

          true ->
            {:halt,
             {:error,
              "services: #{inspect(module)} is not in this node's code (or has no start_link/1)"}}
        end

      other, _ ->
        {:halt, {:error, "services: expected {module, opts} items, got: #{show(other)}"}}
    end)
    |> reversed()
  end

  defp services(other),
    do: {:error, "services: expected a list of {module, opts}, got: #{show(other)}"}

  defp dashboard(nil), do: {:ok, nil}

  defp dashboard(opts) when is_list(opts) do
    with :ok <- only(:dashboard, opts, [:port, :bind, :hosts, :token_file]),
         {:ok, _module} <- dashboard_module(),
         {:ok, port} <- dashboard_port(opts[:port]),
         {:ok, bind} <- bind(opts[:bind]),
         {:ok, hosts} <- dashboard_hosts(opts[:hosts]),
         {:ok, token_file} <- token_file(opts[:token_file]) do
      {:ok,
       [port: port, bind: bind, hosts: hosts] ++
         if(token_file, do: [token_file: token_file], else: [])}
    end
  end

  defp dashboard(other), do: {:error, "dashboard: expected [port: n, ...], got: #{show(other)}"}

  defp dashboard_port(p) when is_integer(p) and p in 0..65_535, do: {:ok, p}

  defp dashboard_port(other),
    do:
      {:error,
       "dashboard: port: expected a port number in 0..65535 (0: any), got: #{show(other)}"}

  # An address as a string ("0.0.0.0", "::") or a tuple ({0, 0, 0, 0}).
  defp bind(nil), do: {:ok, {127, 0, 0, 1}}

  defp bind(b) when is_binary(b) and byte_size(b) <= 64 do
    with true <- String.valid?(b),
         {:ok, address} <- :inet.parse_strict_address(String.to_charlist(b)) do
      {:ok, address}
    else
      _ -> bad_bind(b)
    end
  end

  defp bind(b) when is_tuple(b) do
    if is_list(:inet.ntoa(b)), do: {:ok, b}, else: bad_bind(b)
  end

  defp bind(other), do: bad_bind(other)

  defp bad_bind(b),
    do:
      {:error,
       "dashboard: bind: expected an IP address (\"0.0.0.0\" or {0, 0, 0, 0}), got: #{show(b)}"}

  defp dashboard_hosts(nil), do: {:ok, []}

  defp dashboard_hosts(hosts) when is_list(hosts) do
    if Enum.all?(hosts, &(is_binary(&1) and &1 != "" and String.valid?(&1))),
      do: {:ok, hosts},
      else:
        {:error, "dashboard: hosts: expected a list of host names (strings), got: #{show(hosts)}"}
  end

  defp dashboard_hosts(other),
    do: {:error, "dashboard: hosts: expected a list of host names (strings), got: #{show(other)}"}

  defp token_file(file), do: existing(:"dashboard: token_file", file, :file)

  @doc """
  The options `Tartarus.start_host/2` gets: plugins, persistence and security (neighbours
  are linked later, by `TartarusNode.Boot`, once they answer); `{:error, line}` if the
  trust list or the key pair, checked when the file was read, no longer loads.
  """
  @spec host_options(t()) :: {:ok, keyword()} | {:error, String.t()}
  def host_options(c) do
    with {:ok, trust} <- load_trust(c.trusted),
         {:ok, keys} <- load_keys(c.keys) do
      security = Enum.reject([trust: trust, keys: keys], fn {_, v} -> v == nil end)

      {:ok,
       [plugins: c.plugins] ++
         if(c.data_dir, do: [data_dir: c.data_dir, durable: c.durable], else: []) ++
         if(security == [], do: [], else: [security: security])}
    end
  end

  defp load_trust(nil), do: {:ok, nil}

  defp load_trust(dir) do
    case Tartarus.Security.TrustList.from_dir(dir) do
      {:ok, trust} -> {:ok, trust}
      {:error, reason} -> {:error, "trusted: " <> Tartarus.Security.Keys.format_error(reason)}
    end
  end

  defp load_keys(nil), do: {:ok, nil}

  defp load_keys(dir) do
    case Tartarus.Security.Keys.load(dir) do
      {:ok, keys} ->
        {:ok, keys}

      {:error, reason} ->
        {:error,
         "keys: #{Tartarus.Security.Keys.format_error(reason)} (the directory must hold " <>
           "this host's issuer key pair, issuer.key and issuer.pub)"}
    end
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
        do:
          ["-kernel", "inet_dist_listen_min", "#{c.dist_port}"] ++
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
