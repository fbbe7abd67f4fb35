Code.require_file("support/netns_bed.exs", __DIR__)

defmodule Tartarus.ReleaseTest do
  # The release (`MIX_ENV=prod mix release`, built once per run by Tartarus.NetnsBed) boots
  # from its configuration file alone, and a bad file stops the boot with one line and
  # status 1 (no root needed; the namespace bed, test/netns_test.exs, runs it on a network).
  use ExUnit.Case, async: false

  @moduletag :release
  @moduletag :tmp_dir
  @moduletag timeout: 600_000

  setup_all do
    {root, _secs} = Tartarus.NetnsBed.build_release!()
    %{bin: Path.join(root, "bin/tartarus")}
  end

  defp run(bin, config, command \\ "start") do
    System.cmd(bin, [command],
      env: [{"TARTARUS_CONFIG", config}, {"RELEASE_TMP", Path.join(Path.dirname(config), "tmp")}],
      stderr_to_stdout: true
    )
  end

  test "a bad configuration stops the boot with one clear line and status 1", %{
    bin: bin,
    tmp_dir: dir
  } do
    cases = [
      {"missing.exs", nil, "cannot read it (no such file)"},
      {"syntax.exs", "[node: \"tartarus@127.0.0.1\",", "missing terminator: ]"},
      {"nocookie.exs", "[node: \"tartarus@127.0.0.1\"]", "cookie: required without tls:"},
      {"notls.exs", "[node: \"t@127.0.0.1\", tls: [dir: \"/nonexistent\"]]",
       "tls: cert: no such file /nonexistent/t@127.0.0.1.pem"},
      {"plugin.exs", "[node: \"t@127.0.0.1\", cookie: \"c\", plugins: [x: {:nope, 1}]]",
       "plugins: x: expected {module, opts}"},
      {"key.exs", "[node: \"t@127.0.0.1\", cookie: \"c\", colour: :red]", "unknown key colour:"},
      # Issue 41: GPIO pins with no GPIO backend were simulated in silence; a serial device
      # that is not there booted silently; a data_dir under a file gave a crash dump.
      {"gpio.exs",
       "[node: \"t@127.0.0.1\", cookie: \"c\", plugins: [io: {Tartarus.Plugin.GPIO, pins: [led: {17, :output}]}]]",
       "plugins: io: Tartarus.Plugin.GPIO: no GPIO backend on this node for pins led (line 17)"},
      {"tty.exs",
       "[node: \"t@127.0.0.1\", cookie: \"c\", plugins: [tty: {:serial, \"/dev/nonexistent-41\"}]]",
       "plugins: tty: no such device /dev/nonexistent-41"},
      {"data.exs", "[node: \"t@127.0.0.1\", cookie: \"c\", data_dir: \"/dev/null/data\"]",
       "data_dir: /dev/null is not a directory"}
    ]

    for {file, text, expected} <- cases do
      path = Path.join(dir, file)
      if text, do: File.write!(path, text)
      {out, status} = run(bin, path)
      assert status == 1, out
      assert [line] = String.split(out, "\n", trim: true)
      assert line == "tartarus: bad configuration #{path}: " <> line_tail(line, path)
      assert line =~ expected
    end
  end

  test "a host that cannot start stops the node with one line and status 1, no crash dump", %{
    bin: bin,
    tmp_dir: dir
  } do
    path = Path.join(dir, "node.exs")
    # A plugin module without a check/1 passes the configuration check and fails at start.
    File.write!(path, """
    [node: "tt41bad#{System.unique_integer([:positive])}@127.0.0.1", cookie: "c", host: "pi1",
     plugins: [tty: {Tartarus.Plugin.Serial, speed: 9600}]]
    """)

    {out, status} =
      System.cmd(bin, ["start"], env: env(path, dir), stderr_to_stdout: true, cd: dir)

    assert status == 1, out
    assert out =~ "tartarus: cannot start host pi1: required option :device not given"
    refute out =~ "crash"
    assert Path.wildcard(Path.join(dir, "erl_crash.dump")) == []
  end

  defp line_tail(line, path),
    do: String.replace_prefix(line, "tartarus: bad configuration #{path}: ", "")

  test "the release boots from its configuration file alone", %{bin: bin, tmp_dir: dir} do
    name = "tt29rel#{System.unique_integer([:positive])}@127.0.0.1"
    path = Path.join(dir, "node.exs")

    File.write!(path, """
    [node: #{inspect(name)}, cookie: "tt29", host: "pi1", data_dir: #{inspect(Path.join(dir, "data"))},
     plugins: [temp: {:sensor, signal: [21.5]}]]
    """)

    port =
      Port.open({:spawn_executable, bin}, [
        :binary,
        :exit_status,
        :stderr_to_stdout,
        args: ["start"],
        env: [{~c"TARTARUS_CONFIG", ~c"#{path}"}, {~c"RELEASE_TMP", ~c"#{Path.join(dir, "tmp")}"}]
      ])

    {:os_pid, pid} = Port.info(port, :os_pid)

    try do
      out = await_output(port, "running", "", 180_000)

      assert out =~
               "tartarus: host {:pi1, :\"#{name}\"} running; plugins: temp (Tartarus.Plugin.SimSensor)"

      assert File.dir?(Path.join(dir, "data"))
      # The release's own rpc (plain distribution, the file's cookie) reads the plugin.
      {rpc, 0} = rpc(bin, path)
      assert rpc =~ "{:ok, 21.5}"
    after
      System.cmd("kill", ["-9", "#{pid}"], stderr_to_stdout: true)
    end
  end

  # The documented configuration (rel/node.exs.example) adapted in paths and names only: the
  # node's name and its neighbour's on this machine, the certificates' directory, the HM-10's
  # tty (a socat pseudo-terminal), the data directory, the dashboard on a free port of the
  # loopback.
  defp from_example(dir, name, certs, tty, operator) do
    text =
      File.read!("rel/node.exs.example")
      |> String.replace(~s("tartarus@pi1.local"), inspect(name))
      |> String.replace(~s("tartarus@pi2.local"), ~s("tt41absent@127.0.0.1"))
      |> String.replace(
        ~s(tls: [dir: "/etc/tartarus/certs"]),
        "tls: [dir: #{inspect(certs)}, operator: #{inspect(operator)}]"
      )
      |> String.replace(~s("/dev/serial0"), inspect(tty))
      |> String.replace(~s("/var/lib/tartarus/host"), inspect(Path.join(dir, "data")))
      |> String.replace(~s(port: 4000, bind: "0.0.0.0"), ~s(port: 0, bind: "127.0.0.1"))

    path = Path.join(dir, "node.exs")
    File.write!(path, text)
    path
  end

  defp env(path, dir), do: [{"TARTARUS_CONFIG", path}, {"RELEASE_TMP", Path.join(dir, "tmp")}]

  defp cmd(bin, args, path, dir),
    do: System.cmd(bin, args, env: env(path, dir), stderr_to_stdout: true)

  test "the documented configuration: BLE on a tty, Where am I answered; the operator over TLS (remote, rpc, pid, stop); a bad certificate refused in one line",
       %{bin: bin, tmp_dir: dir} do
    u = System.unique_integer([:positive])
    name = "tt41tls#{u}@127.0.0.1"
    operator = "tt41op#{u}"
    me = "tt41me#{u}"
    certs = Path.join(dir, "certs")

    {:ok, _} =
      Tartarus.Security.Certs.generate(certs, nodes: [name, operator, me], hosts: ["127.0.0.1"])

    # socat's address syntax takes no commas in the path (the tmp_dir has them).
    tty = Path.join(System.tmp_dir!(), "tt41-hm10-#{u}")
    socat = socat!(tty)
    path = from_example(dir, name, certs, tty, operator)
    node = start!(bin, path, dir)

    try do
      out = await_output(node, "running", "", 180_000)

      assert out =~
               "running; plugins: temp (Tartarus.Plugin.SimSensor), beacon (Tartarus.Plugin.Serial)"

      # The example's dashboard (the release carries apps/tartarus_dashboard) serves the node.
      out = await_output(node, ~r{dashboard: http://127\.0\.0\.1:\d+/ .*token}, out, 60_000)
      [url] = Regex.run(~r{http://127\.0\.0\.1:\d+/}, out)
      assert {:ok, 200, info} = TartarusDashboard.http_get(url <> "api/info", 10_000)
      assert Tartarus.JSON.decode!(info)["node"] == name

      # The HM-10 answers a scan; the operator's rpc (TLS, its own certificate) reads it.
      beacon = %TartarusLats.Beacon{
        uuid: "74278bdab64445208f0c720eaf059935",
        major: 1234,
        minor: 1111,
        tx_power: -59,
        rssi: -61
      }

      Port.command(socat, TartarusLats.HM10.encode_scan([beacon]))
      tag = TartarusLats.Beacon.tag_id(beacon)

      # (Counts: the node's database agent takes each second's readings itself.)
      read = ~s|IO.inspect(Tartarus.read_plugin(:pi1, :beacon, :counts))|

      assert eventually(fn ->
               {out, 0} = cmd(bin, ["rpc", read], path, dir)
               out =~ ~r/beacons: [1-9]/ and out =~ ~r/scans: [1-9]/
             end)

      {:os_pid, os_pid} = Port.info(node, :os_pid)
      assert {"#{os_pid}\n", 0} == cmd(bin, ["pid"], path, dir)

      # LATS on the node (the example's services:): the tag keeps being heard, and a
      # Where am I released on the node answers the node's zone.
      for _ <- 1..6 do
        Port.command(socat, TartarusLats.HM10.encode_scan([beacon]))
        Process.sleep(700)
      end

      where_am_i =
        "{:ok, id} = Tartarus.create_mobile_agent(:pi1, TartarusLats.Query.WhereAmI, " <>
          "%{tag: #{inspect(tag)}, label: nil, report: false, cloud: :per_node, repair: false}, owner: self()); " <>
          "receive do {:tartarus_result, ^id, r} -> IO.inspect(r.answer) after 10_000 -> IO.puts(:none) end"

      assert eventually(fn ->
               Port.command(socat, TartarusLats.HM10.encode_scan([beacon]))
               {out, 0} = cmd(bin, ["rpc", where_am_i], path, dir)
               out =~ "{:in_zone, :pi1}"
             end)

      # The adapter unplugged: the node goes on (the plugin waits for it), and so does the
      # operator (only the commands that start a node want their devices there).
      stop_port(socat)
      File.rm(tty)
      assert {"still here\n", 0} = cmd(bin, ["rpc", ~s|IO.puts("still here")|], path, dir)

      # The operator's shell through a pty: evaluates on the node and moves an agent.
      remote = pty!("#{bin} remote", env(path, dir))
      await_pty(remote, "iex(#{name})1>")

      Port.command(
        remote,
        ~S|{:ok, [m]} = Tartarus.compile_string("defmodule Op41 do use Tartarus.Agent; def init(s), do: {:stay, s} end"); {:ok, _} = Tartarus.start_host(:op2); {:ok, id} = Tartarus.create_mobile_agent(:pi1, m, :x); IO.puts("moved: #{inspect(Tartarus.move({id, :pi1}, {:op2, node()}))} on #{node()}")| <>
          "\n"
      )

      await_pty(remote, "moved: :ok on #{name}")

      # While it is attached, its name is taken: one line on the operator's side.
      {out, 1} = cmd(bin, ["rpc", "1"], path, dir)

      assert out ==
               "tartarus: rpc: refused before connecting: #{operator}@127.0.0.1 is in use: another operator command is attached (one at a time per operator certificate)\n"

      quit_pty(remote)

      # A workstation's iex --remsh with the documented flags (OTP's own inet_tls, the
      # option file mix tartarus.gen.certs wrote for its certificate).
      optfile = Path.join(certs, "#{me}.ssl_dist.conf")

      ws =
        pty!(
          "iex --name #{me}@127.0.0.1 --cookie tartarus --erl '-proto_dist inet_tls -ssl_dist_optfile #{optfile} -connect_all false' --remsh #{name}",
          []
        )

      await_pty(ws, "iex(#{name})1>")
      Port.command(ws, "Tartarus.read_plugin(:pi1, :temp, :value) |> elem(0)\n")
      await_pty(ws, ":ok")
      quit_pty(ws)

      # A certificate from another CA is refused before any connection, in one line.
      other = Path.join(dir, "other")
      {:ok, _} = Tartarus.Security.Certs.generate(other, nodes: [operator], hosts: ["127.0.0.1"])
      File.rename!(Path.join(certs, "#{operator}.pem"), Path.join(dir, "op.pem"))
      File.cp!(Path.join(other, "#{operator}.pem"), Path.join(certs, "#{operator}.pem"))
      {out, 1} = cmd(bin, ["rpc", "1"], path, dir)

      assert [line] = String.split(out, "\n", trim: true)

      assert line =~
               "tartarus: rpc: refused before connecting: #{certs}/#{operator}.pem was not issued by this node's CA"

      File.rename!(Path.join(dir, "op.pem"), Path.join(certs, "#{operator}.pem"))

      # And without an operator's certificate at all.
      File.rename!(Path.join(certs, "#{operator}.pem"), Path.join(dir, "op.pem.keep"))
      {out, 1} = cmd(bin, ["pid"], path, dir)
      assert out =~ "tartarus: pid: refused before connecting: no operator certificate"

      File.rename!(Path.join(dir, "op.pem.keep"), Path.join(certs, "#{operator}.pem"))
      assert {_, 0} = cmd(bin, ["stop"], path, dir)
      assert_receive {^node, {:exit_status, 0}}, 60_000
    after
      stop_ptys()
      stop_port(node)
      stop_port(socat)
      File.rm(tty)
    end
  end

  defp start!(bin, path, dir) do
    Port.open({:spawn_executable, bin}, [
      :binary,
      :exit_status,
      :stderr_to_stdout,
      args: ["start"],
      env: for({k, v} <- env(path, dir), do: {~c"#{k}", ~c"#{v}"})
    ])
  end

  defp socat!(link) do
    exe =
      System.find_executable("socat") ||
        flunk("socat is not installed (scripts/test installs it)")

    port =
      Port.open({:spawn_executable, exe}, [
        :binary,
        :exit_status,
        args: ["pty,raw,echo=0,link=#{link}", "STDIO"]
      ])

    assert eventually(fn -> File.exists?(link) end)
    port
  end

  # A terminal session (`script` gives the command a pty, as a person's terminal would).
  # Each is ended, with what it runs, after the test (`stop_ptys/0`), whatever happened.
  defp pty!(command, env) do
    port =
      Port.open({:spawn_executable, System.find_executable("script")}, [
        :binary,
        :exit_status,
        :stderr_to_stdout,
        args: ["-qfc", command, "/dev/null"],
        env: for({k, v} <- env, do: {~c"#{k}", ~c"#{v}"})
      ])

    {:os_pid, pid} = Port.info(port, :os_pid)
    Process.put(:ptys, [pid | Process.get(:ptys, [])])
    port
  end

  defp stop_ptys do
    for pid <- Process.get(:ptys, []), do: kill_tree(pid)
    :ok
  end

  # The process and its descendants (script -> sh -> the VM), by their pids.
  defp kill_tree(pid) do
    {children, _} = System.cmd("pgrep", ["-P", "#{pid}"], stderr_to_stdout: true)
    for child <- String.split(children, "\n", trim: true), do: kill_tree(child)
    System.cmd("kill", ["-9", "#{pid}"], stderr_to_stdout: true)
  end

  defp await_pty(port, pattern, acc \\ "") do
    receive do
      {^port, {:data, data}} ->
        acc = acc <> data
        if acc =~ pattern, do: acc, else: await_pty(port, pattern, acc)

      {^port, {:exit_status, s}} ->
        flunk("the session exited with #{s}:\n#{acc}")
    after
      120_000 -> flunk("no #{inspect(pattern)} in the session:\n#{acc}")
    end
  end

  # Ctrl-G q: the shell's own VM quits (the node goes on).
  defp quit_pty(port) do
    Port.command(port, "\a")
    Process.sleep(300)
    Port.command(port, "q\n")

    receive do
      {^port, {:exit_status, _}} -> :ok
    after
      30_000 -> stop_port(port)
    end
  end

  defp stop_port(port) do
    case Port.info(port, :os_pid) do
      {:os_pid, pid} -> System.cmd("kill", ["-9", "#{pid}"], stderr_to_stdout: true)
      nil -> :ok
    end

    :ok
  end

  defp eventually(fun, tries \\ 60) do
    cond do
      fun.() -> true
      tries == 0 -> false
      true -> Process.sleep(500) && eventually(fun, tries - 1)
    end
  end

  defp rpc(bin, path) do
    System.cmd(bin, ["rpc", "IO.inspect(Tartarus.read_plugin(:pi1, :temp, :value))"],
      env: [{"TARTARUS_CONFIG", path}, {"RELEASE_TMP", Path.join(Path.dirname(path), "tmp")}],
      stderr_to_stdout: true
    )
  end

  # What the port wrote, up to the first time `pattern` is in it (`acc`: what it wrote before).
  defp await_output(port, pattern, acc, timeout) do
    if acc =~ pattern do
      acc
    else
      receive do
        {^port, {:data, data}} ->
          await_output(port, pattern, acc <> data, timeout)

        {^port, {:exit_status, s}} ->
          flunk("the release exited with #{s}:\n#{acc}")
      after
        timeout -> flunk("the release did not start:\n#{acc}")
      end
    end
  end
end
