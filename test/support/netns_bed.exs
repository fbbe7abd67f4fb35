defmodule Tartarus.NetnsBed do
  @moduledoc """
  A test bed of Linux network namespaces (root only): one bridge, one namespace per node,
  each joined to the bridge by a veth pair, addresses from 198.18.29.0/24 (the benchmarking
  range 198.18.0.0/15, never any other), nodes started from the built release
  (`_build/prod/rel/tartarus/bin/tartarus start`, as systemd starts it) with long names
  (`tartarus@198.18.29.<i>`) over TLS distribution, each from its own configuration file.

  A control node (`ctl@198.18.29.200`, in a namespace of its own, with a certificate of its
  own and the same TLS flags) is how the test reaches the nodes: `ctl/3` evaluates code
  there, which calls the nodes with `:erpc`. The test VM itself runs no distribution with them.

  Everything is named with a unique prefix (`tt29-<id>-...`, `tt29<id>...`) and `destroy/1`
  removes exactly that: every process in the bed's namespaces (the nodes, their epmd), the
  namespaces, the bridge, the directory.
  """

  @subnet "198.18.29"
  @ctl 200
  @rel "_build/prod/rel/tartarus"

  @doc """
  Builds the release once per test run (`MIX_ENV=prod mix release --overwrite`) and returns
  `{root, seconds}` (seconds of this call; 0 when already built by this run).

  `variant` `:default` is the release as shipped (the dashboard, no lab application);
  `:tools` is the one built with `TARTARUS_RELEASE_TOOLS=true` (the tooling app too, into
  `_build/prod/rel/tartarus_tools`): the bed's nodes run it, since test (d)'s agent is
  the chaos harness's (`TartarusTools.Chaos.Counter`), which a node restarted from its data
  directory must find on its code path.
  """
  def build_release!(variant \\ :default) do
    case :persistent_term.get({__MODULE__, :release, variant}, nil) do
      nil ->
        t0 = System.monotonic_time(:millisecond)
        rel = if variant == :tools, do: @rel <> "_tools", else: @rel
        # A release built before with other applications keeps their directories under
        # lib/ (--overwrite replaces, it does not remove): start from none.
        File.rm_rf!(Path.expand(rel))
        tools = if variant == :tools, do: "true", else: "false"

        {out, status} =
          System.cmd("mix", ["release", "--overwrite", "--quiet", "--path", rel],
            env: [{"MIX_ENV", "prod"}, {"TARTARUS_RELEASE_TOOLS", tools}],
            stderr_to_stdout: true
          )

        if status != 0, do: raise("MIX_ENV=prod mix release failed:\n#{out}")
        root = Path.expand(rel)
        secs = (System.monotonic_time(:millisecond) - t0) / 1000
        IO.puts("\n[netns] MIX_ENV=prod mix release (#{variant}): #{Float.round(secs, 1)} s")
        :persistent_term.put({__MODULE__, :release, variant}, root)
        {root, secs}

      root ->
        {root, 0}
    end
  end

  @doc "The index of the control node's namespace (`ip/1`, `ns/2`): where the workstation runs."
  def ctl_index, do: @ctl

  @doc "The address of node `i`."
  def ip(i), do: "#{@subnet}.#{i}"

  @doc "The node name of node `i`."
  def node_name(i), do: :"tartarus@#{ip(i)}"

  @doc """
  The bed's plan: names for nodes `1..n` plus `extra` (more indexes, e.g. impostors) and the
  control node, nothing made yet. Register `destroy/1` on it, then `create!/1`.
  """
  def plan(n, extra \\ []) do
    id = :crypto.strong_rand_bytes(2) |> Base.encode16(case: :lower)
    dir = Path.join(System.tmp_dir!(), "tt29-#{id}")

    %{
      id: id,
      dir: dir,
      root: nil,
      bridge: "tt29#{id}br",
      nodes: Enum.to_list(1..n),
      all: Enum.to_list(1..n) ++ extra ++ [@ctl],
      certs: Path.join(dir, "certs"),
      ports: :ets.new(:netns_ports, [:public, :set])
    }
  end

  @doc """
  Makes the planned bed: the bridge, the namespaces and their links, certificates for every
  node and the control node (`Tartarus.Security.Certs`, as `mix tartarus.gen.certs` makes
  them); starts the control node. Returns the bed.
  """
  def create!(bed) do
    {root, _} = build_release!(:tools)
    File.mkdir_p!(bed.dir)
    ip!(["link", "add", bed.bridge, "type", "bridge"])
    ip!(["link", "set", bed.bridge, "up"])
    Enum.each(bed.all, &add_namespace!(bed, &1))

    # `operator` (no host: operator@<each address>) is the operator's certificate for the
    # release's remote, rpc, stop and pid (TartarusNode.Operator).
    names =
      Enum.map(bed.all, &"#{if &1 == @ctl, do: "ctl", else: "tartarus"}@#{ip(&1)}") ++
        ["me@#{ip(@ctl)}", "operator"]

    hosts = Enum.map(bed.all, &ip/1)
    {:ok, _} = Tartarus.Security.Certs.generate(bed.certs, nodes: names, hosts: hosts)
    bed = %{bed | root: root}
    Map.put(bed, :ctl, spawn(fn -> ctl_keeper(bed) end))
  end

  @doc "The namespace of node `i`."
  def ns(bed, i), do: "tt29-#{bed.id}-#{i}"

  @doc "The root-side veth of node `i` (the link `link/3` takes down)."
  def veth(bed, i), do: "tt29#{bed.id}v#{i}"

  defp add_namespace!(bed, i) do
    ns = ns(bed, i)
    ip!(["netns", "add", ns])
    ip!(["link", "add", veth(bed, i), "type", "veth", "peer", "name", "eth0", "netns", ns])
    ip!(["link", "set", veth(bed, i), "master", bed.bridge, "up"])
    ip!(["-n", ns, "addr", "add", "#{ip(i)}/24", "dev", "eth0"])
    ip!(["-n", ns, "link", "set", "eth0", "up"])
    ip!(["-n", ns, "link", "set", "lo", "up"])
  end

  @doc "Takes the link of node `i` down or up (`ip link set <veth> down|up`)."
  def link(bed, i, state) when state in [:down, :up],
    do: ip!(["link", "set", veth(bed, i), Atom.to_string(state)])

  @doc "Removes everything the bed made; safe to call twice, and on a half-made bed."
  def destroy(bed) do
    for i <- bed.all do
      ns = ns(bed, i)
      kill_all(ns)
      # Deleting the root end removes the pair now (a namespace may outlive its deletion
      # while the kernel closes its sockets).
      System.cmd("ip", ["link", "del", veth(bed, i)], stderr_to_stdout: true)
      System.cmd("ip", ["netns", "del", ns], stderr_to_stdout: true)
    end

    System.cmd("ip", ["link", "del", bed.bridge], stderr_to_stdout: true)
    File.rm_rf(bed.dir)
    :ok
  end

  @doc "Namespaces and links of this bed still present (for the cleanup assertion)."
  def leftovers(bed) do
    {netns, _} = System.cmd("ip", ["netns", "list"])
    {links, _} = System.cmd("ip", ["-o", "link", "show"])

    Enum.filter(String.split(netns <> links, "\n"), fn line ->
      String.contains?(line, "tt29-#{bed.id}-") or String.contains?(line, "tt29#{bed.id}")
    end)
  end

  defp kill_all(ns) do
    for pid <- pids(ns), do: System.cmd("kill", ["-9", pid], stderr_to_stdout: true)
  end

  defp pids(ns) do
    case System.cmd("ip", ["netns", "pids", ns], stderr_to_stdout: true) do
      {out, 0} -> String.split(out, "\n", trim: true)
      _ -> []
    end
  end

  @doc """
  Writes node `i`'s configuration file (`config` is the keyword list, over the defaults:
  its name, host `h<i>`, TLS with its certificate, data directory) and starts the release
  in its namespace with `bin/tartarus start`. Returns the path of the file.
  """
  def start_node!(bed, i, config \\ []) do
    ndir = Path.join(bed.dir, "n#{i}")
    File.mkdir_p!(ndir)

    defaults = [
      node: "tartarus@#{ip(i)}",
      host: "h#{i}",
      tls: [dir: bed.certs],
      data_dir: Path.join(ndir, "data")
    ]

    config = Keyword.merge(defaults, config) |> Enum.reject(fn {_, v} -> v == nil end)
    path = Path.join(ndir, "node.exs")
    File.write!(path, inspect(config, limit: :infinity, pretty: true))
    launch(bed, i, path, ndir, "start")
    path
  end

  @doc "Runs `bin/tartarus <command>` in node `i`'s namespace with the configuration at `path`."
  def launch(bed, i, path, ndir, command) do
    env = for {k, v} <- release_env(path, ndir), do: {~c"#{k}", if(v, do: ~c"#{v}", else: false)}
    keeper = spawn(fn -> keep_port(bed, i, command, env) end)
    :ets.insert(bed.ports, {i, keeper})
    keeper
  end

  @doc """
  The environment of `bin/tartarus` for the configuration at `path` (`RELEASE_TMP` in
  `ndir`; `nil` unsets).
  """
  def release_env(path, ndir) do
    [
      {"TARTARUS_CONFIG", path},
      {"RELEASE_TMP", Path.join(ndir, "tmp")},
      # The machine's may say 127.0.0.1; a node's epmd must answer on its address.
      {"ERL_EPMD_ADDRESS", nil}
    ]
  end

  @doc """
  Runs `bin/tartarus <args>` to its end in node `i`'s namespace, as an operator on that
  machine would, with the configuration at `path` (see `release_env/2`): `{output, status}`.
  """
  def release_cmd(bed, i, path, args) do
    System.cmd("ip", ["netns", "exec", ns(bed, i), Path.join(bed.root, "bin/tartarus") | args],
      env: release_env(path, Path.dirname(path)),
      stderr_to_stdout: true
    )
  end

  @doc "The shell command line that runs `command` (a command line) in node `i`'s namespace."
  def in_ns(bed, i, command), do: "ip netns exec #{ns(bed, i)} #{command}"

  @doc "The OS pids of the processes in node `i`'s namespace."
  def ns_pids(bed, i), do: pids(ns(bed, i))

  defp keep_port(bed, i, command, env) do
    port =
      Port.open({:spawn_executable, System.find_executable("ip")}, [
        :binary,
        :exit_status,
        :stderr_to_stdout,
        args: [
          "netns",
          "exec",
          ns(bed, i),
          "nice",
          "-n",
          "19",
          Path.join(bed.root, "bin/tartarus"),
          command
        ],
        env: env
      ])

    keep_loop(port, "", nil)
  end

  defp keep_loop(port, out, status) do
    receive do
      {^port, {:data, data}} ->
        keep_loop(port, out <> data, status)

      {^port, {:exit_status, s}} ->
        keep_loop(port, out, s)

      {:output, from} ->
        send(from, {:output, self(), out, status}) && keep_loop(port, out, status)
    end
  end

  @doc "What node `i`'s release printed so far, and its exit status (nil while it runs)."
  def output(bed, i) do
    [{^i, keeper}] = :ets.lookup(bed.ports, i)
    send(keeper, {:output, self()})

    receive do
      {:output, ^keeper, out, status} -> {out, status}
    after
      5_000 -> {"", nil}
    end
  end

  @doc "Waits (up to `ms`) until node `i` printed that its host runs; raises with its output otherwise."
  def await_up!(bed, i, ms \\ 180_000) do
    deadline = System.monotonic_time(:millisecond) + ms
    await_up(bed, i, deadline)
  end

  defp await_up(bed, i, deadline) do
    {out, status} = output(bed, i)

    cond do
      out =~ "tartarus: host" and out =~ "running" ->
        :ok

      status != nil or System.monotonic_time(:millisecond) > deadline ->
        raise "node #{i} did not start (status #{inspect(status)}):\n#{out}"

      true ->
        Process.sleep(300)
        await_up(bed, i, deadline)
    end
  end

  @doc "SIGKILLs node `i`'s VM (every process in its namespace but epmd)."
  def kill_node(bed, i) do
    for pid <- ns_pids(bed, i),
        {:ok, cmd} <- [File.read("/proc/#{pid}/cmdline")],
        not String.contains?(cmd, "epmd") do
      System.cmd("kill", ["-9", pid], stderr_to_stdout: true)
    end

    :ok
  end

  # -- the control node -------------------------------------------------------------------

  @ctl_loop ~S"""
  defmodule Ctl do
    def loop do
      case IO.gets("") do
        :eof -> System.halt(0)
        line ->
          code = Base.decode64!(String.trim(line))
          result =
            try do
              {:ok, elem(Code.eval_string(code), 0)}
            catch
              kind, reason -> {:error, {kind, reason}}
            end
          IO.puts("CTLRESULT " <> Base.encode64(:erlang.term_to_binary(result)))
          loop()
      end
    end
  end
  IO.puts("CTLREADY")
  Ctl.loop()
  """

  # The control node's port, owned by this process, which answers `ctl/3`'s requests.
  defp ctl_keeper(bed) do
    name = "ctl@#{ip(@ctl)}"
    ebin = Path.wildcard(Path.join(bed.root, "lib/tartarus-*/ebin")) |> hd()
    optfile = Tartarus.Security.TLSDist.optfile_path(name, bed.certs)

    erl =
      "-proto_dist tartarus_tls -ssl_dist_optfile #{optfile} -pa #{ebin} -connect_all false -kernel net_ticktime 4"

    port =
      Port.open({:spawn_executable, System.find_executable("ip")}, [
        :binary,
        {:line, 10_000_000},
        :exit_status,
        args:
          ["netns", "exec", ns(bed, @ctl), "elixir", "--name", name, "--cookie", "tartarus"] ++
            ["--erl", erl, "-e", @ctl_loop],
        env: [{~c"ERL_EPMD_ADDRESS", false}]
      ])

    ready =
      receive do
        {^port, {:data, {:eol, "CTLREADY"}}} -> :ok
        {^port, {:exit_status, s}} -> {:error, "the control node exited with #{s}"}
      after
        120_000 -> {:error, "the control node did not start"}
      end

    ctl_serve(port, ready)
  end

  defp ctl_serve(port, ready) do
    receive do
      {:eval, from, ref, code, timeout} ->
        reply =
          if ready == :ok do
            Port.command(port, Base.encode64(code) <> "\n")
            ctl_reply(port, timeout)
          else
            ready
          end

        send(from, {ref, reply})
        ctl_serve(port, ready)
    end
  end

  @doc """
  Evaluates `code` (Elixir source) on the control node and returns its value (`{:ok, v}`),
  or `{:error, {kind, reason}}` if it raised (or `{:error, message}` if the control node is
  not there).
  """
  def ctl(bed, code, timeout \\ 300_000) do
    ref = make_ref()
    send(bed.ctl, {:eval, self(), ref, code, timeout})

    receive do
      {^ref, reply} -> reply
    after
      timeout + 10_000 -> raise "the control node did not answer in #{timeout} ms"
    end
  end

  defp ctl_reply(port, timeout) do
    receive do
      {^port, {:data, {:eol, "CTLRESULT " <> b64}}} -> :erlang.binary_to_term(Base.decode64!(b64))
      {^port, {:data, _other}} -> ctl_reply(port, timeout)
      {^port, {:exit_status, s}} -> {:error, "the control node exited with #{s}"}
    after
      timeout -> {:error, "the control node did not answer in #{timeout} ms"}
    end
  end

  @doc """
  Runs `code` in a one-off `elixir` VM in the control namespace, as a user's shell would
  attach: `--name me@198.18.29.200`, its own certificate, the TLS flags of
  `Tartarus.Security.TLSDist.erl_flags/2`. Returns `{output, exit_status}`.
  """
  def shell(bed, code) do
    name = "me@#{ip(@ctl)}"
    flags = Tartarus.Security.TLSDist.erl_flags(name, bed.certs)
    # The release's tartarus ebin, not this test VM's: the shell runs what the nodes run.
    ebin = Path.wildcard(Path.join(bed.root, "lib/tartarus-*/ebin")) |> hd()
    flags = Enum.take(flags, 4) ++ ["-pa", ebin, "-connect_all", "false"]

    System.cmd(
      "ip",
      ["netns", "exec", ns(bed, @ctl), "elixir", "--name", name, "--cookie", "tartarus"] ++
        ["--erl", Enum.join(flags, " "), "-e", code],
      stderr_to_stdout: true,
      env: [{"ERL_EPMD_ADDRESS", nil}]
    )
  end

  @doc "As `ctl/3`, returning the value or raising."
  def ctl!(bed, code, timeout \\ 300_000) do
    case ctl(bed, code, timeout) do
      {:ok, value} -> value
      {:error, e} -> raise "on the control node: #{inspect(e)}\n#{code}"
    end
  end

  defp ip!(args) do
    case System.cmd("ip", args, stderr_to_stdout: true) do
      {_, 0} -> :ok
      {out, s} -> raise "ip #{Enum.join(args, " ")} failed (#{s}): #{out}"
    end
  end
end
