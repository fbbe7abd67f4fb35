Code.require_file("support/netns_bed.exs", __DIR__)
Code.require_file("support/release_session.exs", __DIR__)

defmodule Tartarus.ReleaseTest do
  # The release (`MIX_ENV=prod mix release`, built once per run by Tartarus.NetnsBed) boots
  # from its configuration file alone, and a bad file stops the boot with one line and
  # status 1 (no root needed; the namespace bed, test/netns_test.exs, runs it on a network).
  use ExUnit.Case, async: false

  import Tartarus.ReleaseSession

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
       "data_dir: /dev/null is not a directory"},
      # Issue 44: these raised (a stack trace at boot), booted a node whose ticker crashed in
      # a loop, or ran what a node name held (status 7).
      {"tlsdir.exs", "[node: \"t@127.0.0.1\", tls: [dir: 123]]", "tls: dir: expected a path"},
      {"sensor.exs", "[node: \"t@127.0.0.1\", cookie: \"c\", plugins: [temp: {:sensor, [1, 2]}]]",
       "plugins: temp: options: expected a keyword list"},
      {"throw.exs", "throw(:config)", "evaluating it threw :config"},
      {"exit.exs", "exit(:bye)", "evaluating it exited with :bye"},
      {"keys.exs", "[node: \"t@127.0.0.1\", cookie: \"c\", keys: #{inspect(dir)}]",
       "keys: cannot access key file #{dir}/issuer.key"},
      {"tick.exs", "[node: \"t@127.0.0.1\", cookie: \"c\", net_ticktime: 10 ** 40]",
       "net_ticktime: expected an integer in 1..3600"},
      {"name.exs", "[node: \"t4rel@127.0.0.1 --eval System.halt(7)\", cookie: \"c\"]",
       "node: expected name@host"},
      {"datadir.exs",
       "[node: \"t@127.0.0.1\", cookie: \"c\", data_dir: #{inspect(Path.join(dir, String.duplicate("d", 300)))}]",
       "(file name too long)"},
      {"big.exs", big_file(200_000), "it has more than 262144 bytes (256 KiB)"}
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
    # A plugin module without a check/1 passes the configuration check and fails at start
    # (the serial plugin's options are checked by Tartarus.Plugin.Serial.check/1 now).
    File.write!(path, """
    [node: "tt41bad#{System.unique_integer([:positive])}@127.0.0.1", cookie: "c", host: "pi1",
     plugins: [temp: {Tartarus.Plugin.SimSensor, []}]]
    """)

    {out, status} =
      System.cmd(bin, ["start"], env: env(path, dir), stderr_to_stdout: true, cd: dir)

    assert status == 1, out
    assert out =~ "tartarus: cannot start host pi1: "
    assert out =~ "signal"
    refute out =~ "crash"
    assert Path.wildcard(Path.join(dir, "erl_crash.dump")) == []
  end

  defp big_file(n) do
    neighbours =
      Enum.map_join(1..n, ",\n", fn i -> "  h#{i}: \"t@10.0.#{div(i, 256)}.#{rem(i, 256)}\"" end)

    "[node: \"t@127.0.0.1\", cookie: \"c\", neighbours: [\n#{neighbours}\n]]"
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
    # The documented configuration adapted in paths and names only: the node's name and its
    # neighbour's on this machine, the certificates' directory, the HM-10's tty, the data
    # directory.
    path =
      from_example!(
        dir,
        example_paths(name, certs, operator, {:pi2, "tt41absent@127.0.0.1"}, tty, dir)
      )

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
      hear(socat)
      tag = TartarusLats.Beacon.tag_id(beacon())

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
        hear(socat)
        Process.sleep(700)
      end

      assert eventually(fn ->
               hear(socat)
               {out, 0} = cmd(bin, ["rpc", where_am_i(:pi1, tag)], path, dir)
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

  defp rpc(bin, path) do
    System.cmd(bin, ["rpc", "IO.inspect(Tartarus.read_plugin(:pi1, :temp, :value))"],
      env: [{"TARTARUS_CONFIG", path}, {"RELEASE_TMP", Path.join(Path.dirname(path), "tmp")}],
      stderr_to_stdout: true
    )
  end
end
