defmodule TartarusNode.ConfigTest do
  use ExUnit.Case, async: true
  doctest TartarusNode.Config
  doctest TartarusNode.Operator

  alias TartarusNode.Config

  @moduletag :tmp_dir

  defp write(dir, text) do
    path = Path.join(dir, "node.exs")
    File.write!(path, text)
    path
  end

  test "a full file is read: plugins, neighbours, TLS files, persistence, dashboard", %{
    tmp_dir: dir
  } do
    certs = Path.join(dir, "certs")
    File.mkdir_p!(certs)

    for f <- ~w(tartarus@198.18.0.1.pem tartarus@198.18.0.1.key ca.pem),
        do: File.write!(Path.join(certs, f), "x")

    path =
      write(dir, """
      [
        node: "tartarus@198.18.0.1",
        host: "h1",
        tls: [dir: #{inspect(certs)}],
        neighbours: [h2: "tartarus@198.18.0.2"],
        plugins: [temp: {:sensor, unit: "K"}, io: {Tartarus.Plugin.GPIO, pins: [led: {17, :output}], backend: Tartarus.Plugin.GPIO.Sim}],
        data_dir: #{inspect(Path.join(dir, "data"))},
        durable: true,
        dashboard: [port: 4000, bind: "0.0.0.0"]
      ]
      """)

    assert {:ok, c} = Config.read(path)
    assert c.host == :h1 and c.cookie == "tartarus" and c.durable
    assert c.tls.ca == Path.join(certs, "ca.pem")
    assert c.neighbours == [h2: :"tartarus@198.18.0.2"]
    assert [temp: {Tartarus.Plugin.SimSensor, temp}, io: {Tartarus.Plugin.GPIO, _}] = c.plugins
    assert temp[:unit] == "K" and length(temp[:signal]) == 60
    assert c.dashboard[:bind] == {0, 0, 0, 0}

    flags = Config.erl_flags(c, "/x/ssl_dist.conf")

    assert ["-proto_dist", "tartarus_tls", "-ssl_dist_optfile", "/x/ssl_dist.conf"] =
             Enum.take(flags, -4)

    assert {:ok, host_opts} = Config.host_options(c)
    assert host_opts[:data_dir] == Path.join(dir, "data")
    assert [server: server, client: _] = Config.optfile_terms(c)
    assert server[:fail_if_no_peer_cert]
  end

  test "every fault is one line naming the file and what is wrong", %{tmp_dir: dir} do
    cases = [
      {"[node: \"x\"", "missing terminator"},
      {"[node: \"nohost\", cookie: \"c\"]", "node: expected name@host"},
      {"[node: \"a@b.c\", tls: [dir: \"/nonexistent\"]]",
       "tls: cert: no such file /nonexistent/a@b.c.pem"},
      {"[node: \"a@b.c\", cookie: \"c\", plugins: [x: {:serial, 5}]]", "plugins: x: expected"},
      {"[node: \"a@b.c\", cookie: \"c\", plugins: [x: {Enum, []}]]",
       "Enum is not a plugin module"},
      {"[node: \"a@b.c\", cookie: \"c\", durable: true]", "durable: true needs data_dir:"},
      {"[node: \"a@b.c\", cookie: \"c\", dashboard: [port: 4000, bind: \"nowhere\"]]",
       "dashboard: bind"},
      {"[node: \"a@b.c\", cookie: \"c\", trusted: \"/nonexistent\"]",
       "trusted: no such directory"},
      {"[node: \"a@b.c\", cookie: \"c\", neighbours: [h2: \"nonode\"]]", "neighbours: h2"},
      {"raise \"boom\"", "evaluating it raised RuntimeError: boom"},
      {"[node: \"a@b.c\", cookie: \"c\", plugins: [io: {Tartarus.Plugin.GPIO, pins: [led: {17, :output}]}]]",
       "plugins: io: Tartarus.Plugin.GPIO: no GPIO backend on this node for pins led (line 17)"},
      {"[node: \"a@b.c\", cookie: \"c\", plugins: [tty: {:serial, \"/dev/nonexistent-41\"}]]",
       "plugins: tty: no such device /dev/nonexistent-41 (plug it in, or say hotplug: true"},
      {"[node: \"a@b.c\", cookie: \"c\", data_dir: #{inspect(Path.join(file_in(dir), "data"))}]",
       "data_dir: #{file_in(dir)} is not a directory"},
      {"[node: \"a@b.c\", cookie: \"c\", tls: [dir: \"/x\", operator: \"a b\"]]",
       "tls: cert: no such file"},
      {"[node: \"a@b.c\", cookie: \"c\", services: [{Nope.Service41, []}]]",
       "services: Nope.Service41 is not in this node's code"}
    ]

    for {text, expected} <- cases do
      path = write(dir, text)
      assert {:error, line} = Config.read(path)
      assert line =~ "tartarus: bad configuration #{path}: "
      assert line =~ expected
      refute line =~ "\n"
    end
  end

  defp file_in(dir) do
    path = Path.join(dir, "a-file")
    File.write!(path, "")
    path
  end

  test "a device that may come later (hotplug: true) is taken; the rpc side takes any path" do
    spec = {:serial, "/dev/nonexistent-41", hotplug: true}
    assert {:ok, c} = Config.check(node: "a@b.c", cookie: "c", plugins: [tty: spec])
    assert [tty: {Tartarus.Plugin.Serial, opts}] = c.plugins
    assert opts[:device] == "/dev/nonexistent-41" and not Keyword.has_key?(opts, :hotplug)

    assert {:ok, _} =
             Config.check(
               [node: "a@b.c", cookie: "c", plugins: [tty: {:serial, "/dev/nonexistent-41"}]],
               devices: :any
             )
  end

  test "a BLE plugin finds the receiver an application on the code path declares, with no configuration" do
    # As in the release's check VM (no sys.config): nothing configured, LATS's .app says it.
    assert Application.get_env(:tartarus_tools, :ble_plugin) == nil
    assert {:ok, c} = Config.check(node: "a@b.c", cookie: "c", plugins: [b: {:ble, "/dev/null"}])
    assert [b: {Tartarus.Plugin.Serial, opts}] = c.plugins
    assert opts[:decoder] == TartarusLats.HM10.Receiver and opts[:device] == "/dev/null"
  end

  test "the dashboard is the one an application provides (the dashboard app here)" do
    assert Config.dashboard_module() == {:ok, TartarusDashboard}
    assert {:ok, c} = Config.check(node: "a@b.c", cookie: "c", dashboard: [port: 0])
    assert c.dashboard[:port] == 0
  end

  test "the operator's commands dial without the node's listening port" do
    {:ok, c} = Config.check(node: "a@198.18.0.1", cookie: "x", dist_port: 9100)
    refute "inet_dist_listen_min" in Config.erl_flags(c, "/o", :client)
    assert "inet_dist_listen_min" in Config.erl_flags(c, "/o")
  end

  test "short names when the host part has no dot and is no address" do
    assert {:ok, %{distribution: :sname}} = Config.check(node: "a@pi", cookie: "c")
    assert {:ok, %{distribution: :name}} = Config.check(node: "a@pi.local", cookie: "c")
  end

  # Issue 44: every failure one line, never a raise, at the check or at boot.
  defp refused(dir, text) do
    path = write(dir, text)
    assert {:error, line} = Config.read(path)
    assert line =~ "tartarus: bad configuration #{path}: "
    refute line =~ "\n"
    line
  end

  test "values of the wrong type are one line, not a raise (six files raised before)", %{
    tmp_dir: dir
  } do
    ok = ~s(node: "a@b.c", cookie: "c")

    cases = [
      {"[#{ok}, tls: [dir: 123]]", "tls: dir: expected a path, got: 123"},
      {"[#{ok}, tls: [1, 2]]", "tls: expected a keyword list"},
      {"[#{ok}, plugins: [temp: {:sensor, [1, 2]}]]",
       "plugins: temp: options: expected a keyword list, got: [1, 2]"},
      {"[#{ok}, plugins: [t: {:serial, \"/dev/null\", [1]}]]", "plugins: t: options: expected"},
      {"[#{ok}, plugins: [t: {:sensor, signal: [1, :a]}]]", "signal: expected a non-empty list of numbers"},
      {"[#{ok}, plugins: [t: {:sensor, unit: 5}]]", "plugins: t: unit: expected a string"},
      {"[#{ok}, plugins: [t: {:serial, \"/dev/null\", speed: \"fast\"}]]",
       "plugins: t: invalid options given to Tartarus.Plugin.Serial for key :speed"},
      {"[#{ok}, plugins: [t: {:sensor, []}, t: {:sensor, []}]]", "plugins: t: given twice"},
      {"[#{ok}, dashboard: [port: 4000, bind: {999, 0, 0, 0}]]", "dashboard: bind: expected an IP address"},
      {"[#{ok}, dashboard: [port: 4000, bind: :any]]", "dashboard: bind: expected an IP address"},
      {"[#{ok}, dashboard: [port: 4000, bind: <<255>>]]", "dashboard: bind: expected an IP address"},
      {"[#{ok}, dashboard: [port: 4000, hosts: \"pi.local\"]]", "dashboard: hosts: expected a list"},
      {"[#{ok}, dashboard: [port: 4000, token_file: 7]]", "dashboard: token_file: expected a path"},
      {"[#{ok}, host: String.duplicate(\"h\", 300)]", "host: expected a name"},
      {"[#{ok}, host: \"a b\"]", "host: expected a name"},
      {"[#{ok}, data_dir: \"a\\0b\"]", "data_dir: expected a path"},
      {"[#{ok}, services: [{Enum, [1]}]]", "services: Enum: expected a keyword list"},
      {"[node: \"a@b.c\", node: \"c@d.e\", cookie: \"c\"]", "node: given twice"},
      {"[node: \"a@b.c\", cookie: \"two words\"]", "cookie: expected 1 to 255 printable ASCII"},
      {"[node: \"a@b.c\", cookie: String.duplicate(\"c\", 256)]", "cookie: expected 1 to 255"},
      {"throw(:config)", "evaluating it threw :config"},
      {"exit(:bye)", "evaluating it exited with :bye"},
      {"spawn_link(fn -> exit(:linked) end)\nProcess.sleep(5_000)\n[#{ok}]",
       "evaluating it stopped with :linked"},
      {"raise \"two\\nlines\"", "evaluating it raised RuntimeError: two lines"},
      {"Process.exit(self(), :kill)", "evaluating it stopped with :killed"}
    ]

    for {text, expected} <- cases do
      line = refused(dir, text)
      assert line =~ expected, "#{text}: #{line}"
    end
  end

  test "a dashboard address may be a tuple, as the dashboard's own option is", %{tmp_dir: dir} do
    path = write(dir, ~s([node: "a@b.c", cookie: "c", dashboard: [port: 0, bind: {0, 0, 0, 0}]]))
    assert {:ok, c} = Config.read(path)
    assert c.dashboard[:bind] == {0, 0, 0, 0}
  end

  test "a plugin whose own check raises is one line naming it", %{tmp_dir: dir} do
    text = "[node: \"a@b.c\", cookie: \"c\", plugins: [p: {#{inspect(__MODULE__.Raising)}, []}]]"
    assert refused(dir, text) =~ "plugins: p: checking it raised RuntimeError: no check today"
  end

  defmodule Raising do
    @moduledoc false
    def init(_), do: {:ok, nil}
    def check(_), do: raise("no check today")
  end

  test "numbers have ranges: net_ticktime, ports, intervals", %{tmp_dir: dir} do
    ok = ~s(node: "a@b.c", cookie: "c")

    for {text, expected} <- [
          {"[#{ok}, net_ticktime: 10 ** 40]", "net_ticktime: expected an integer in 1..3600"},
          {"[#{ok}, net_ticktime: 0]", "net_ticktime: expected an integer in 1..3600"},
          {"[#{ok}, net_ticktime: 3601]", "net_ticktime: expected an integer in 1..3600"},
          {"[#{ok}, net_ticktime: 1.5]", "net_ticktime: expected an integer in 1..3600"},
          {"[#{ok}, dist_port: 0]", "dist_port: expected an integer in 1..65535"},
          {"[#{ok}, dist_port: 70_000]", "dist_port: expected an integer in 1..65535"},
          {"[#{ok}, dashboard: [port: -1]]", "dashboard: port: expected a port number"},
          {"[#{ok}, dashboard: [port: 65_536]]", "dashboard: port: expected a port number"},
          {"[#{ok}, plugins: [t: {:sensor, interval_ms: 0}]]", "interval_ms: expected a positive"}
        ] do
      assert refused(dir, text) =~ expected, text
    end

    assert {:ok, %{net_ticktime: 3600}} = Config.check(node: "a@b.c", cookie: "c", net_ticktime: 3600)
  end

  test "node names are names before they reach the VM's command line", %{tmp_dir: dir} do
    for name <- [
          "t4rel@127.0.0.1 --eval System.halt(7)",
          "t4rel@127.0.0.1;reboot",
          "t4rel@$(reboot)",
          "t4 rel@127.0.0.1",
          "t@h@i",
          "t@-eval",
          "t@" <> String.duplicate("h", 260)
        ] do
      assert refused(dir, "[node: #{inspect(name)}, cookie: \"c\"]") =~ "node: expected name@host"

      assert refused(dir, "[node: \"a@b.c\", cookie: \"c\", neighbours: [h2: #{inspect(name)}]]") =~
               "neighbours: h2: expected name@host"
    end

    assert refused(dir, "[node: \"a@b.c\", cookie: \"c\", neighbours: [\"a b\": \"n@h\"]]") =~
             "neighbours: a b: expected a name"

    assert {:ok, %{distribution: :name}} = Config.check(node: "n@::1", cookie: "c")
    assert {:ok, %{distribution: :name}} = Config.check(node: "n_1-x@10.0.0.1", cookie: "c")
  end

  test "keys: and trusted: must load, and data_dir: must take a file, as boot will need", %{
    tmp_dir: dir
  } do
    empty = Path.join(dir, "empty")
    File.mkdir_p!(empty)
    ok = ~s(node: "a@b.c", cookie: "c")

    assert refused(dir, "[#{ok}, keys: #{inspect(empty)}]") =~
             "keys: cannot access key file #{empty}/issuer.key"

    bad_trust = Path.join(dir, "trusted")
    File.mkdir_p!(bad_trust)
    File.write!(Path.join(bad_trust, "x.pub"), "short")
    assert refused(dir, "[#{ok}, trusted: #{inspect(bad_trust)}]") =~ "trusted: invalid key file"

    long = Path.join(dir, String.duplicate("d", 300))

    assert refused(dir, "[#{ok}, data_dir: #{inspect(long)}]") =~
             "data_dir: cannot make #{long} (file name too long)"

    keys = Path.join(dir, "keys")
    :ok = Tartarus.Security.Keys.save(Tartarus.Security.Keys.generate(), keys)
    path = write(dir, "[#{ok}, keys: #{inspect(keys)}, data_dir: #{inspect(Path.join(dir, "d"))}]")
    assert {:ok, c} = Config.read(path)
    assert File.dir?(Path.join(dir, "d")) and File.ls!(Path.join(dir, "d")) == []
    assert {:ok, opts} = Config.host_options(c)
    assert opts[:security][:keys].public

    # Gone between the check and the boot: one line there too, not a raise.
    File.rm!(Path.join(keys, "issuer.key"))
    assert {:error, "keys: cannot access key file " <> _} = Config.host_options(c)
  end

  test "what evaluating the file prints goes to standard error, not to env.sh's assignments", %{
    tmp_dir: dir
  } do
    path = write(dir, ~s{IO.puts("RELEASE_NODE=evil")\n[node: "a@b.c", cookie: "c"]})

    err =
      ExUnit.CaptureIO.capture_io(:stderr, fn ->
        assert ExUnit.CaptureIO.capture_io(fn -> assert {:ok, _} = Config.read(path) end) == ""
      end)

    assert err =~ "RELEASE_NODE=evil"
  end

  test "200,000 neighbours are checked in linear time; a file that big is refused by its size",
       %{tmp_dir: dir} do
    n = 200_000
    nodes = for i <- 0..255, do: "tartarus@10.0.0.#{i}"
    nodes = List.to_tuple(nodes)
    neighbours = for i <- 1..n, do: {:"h44_#{i}", elem(nodes, rem(i, 256))}
    assert {:ok, c} = Config.check(node: "a@b.c", cookie: "c", neighbours: neighbours)
    assert length(c.neighbours) == n
    assert hd(c.neighbours) == {:h44_1, :"tartarus@10.0.0.1"}

    body = Enum.map_join(1..n, ",\n", fn i -> "  h44_#{i}: \"#{elem(nodes, rem(i, 256))}\"" end)
    line = refused(dir, "[node: \"a@b.c\", cookie: \"c\", neighbours: [\n#{body}\n]]")
    assert line =~ "it has more than 262144 bytes (256 KiB), the most a node's file may have"

    # Whatever the path is: no more than the bound is read.
    assert {:error, zero} = Config.read("/dev/zero")
    assert zero =~ "it has more than 262144 bytes"

    # Under the bound the file is read whole: 5,000 neighbours (about 140 KB).
    body = Enum.map_join(1..5_000, ",\n", fn i -> "  h44_#{i}: \"#{elem(nodes, rem(i, 256))}\"" end)
    path = write(dir, "[node: \"a@b.c\", cookie: \"c\", neighbours: [\n#{body}\n]]")
    assert {:ok, c} = Config.read(path)
    assert length(c.neighbours) == 5_000
  end
end
