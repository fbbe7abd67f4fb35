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

    assert Config.host_options(c)[:data_dir] == Path.join(dir, "data")
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
end
