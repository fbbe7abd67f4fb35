defmodule TartarusTools.NodeTaskTest do
  use ExUnit.Case, async: true

  alias Mix.Tasks.Tartarus.Node, as: NodeTask

  @moduletag :tmp_dir

  test "lists the plugins it attaches, or says none" do
    assert NodeTask.plugins_line([]) == "plugins: none"

    assert NodeTask.plugins_line(NodeTask.plugins!(sensor: "temp", serial: "/dev/ttyS9")) ==
             "plugins: temp (Tartarus.Plugin.SimSensor), serial (Tartarus.Plugin.Serial)"
  end

  test "warns about every device path that does not exist", %{tmp_dir: dir} do
    present = Path.join(dir, "tty")
    File.write!(present, "")

    assert NodeTask.device_warnings(ble: "/dev/nonexistent-31", serial: present) == [
             "warning: --ble /dev/nonexistent-31: no such file; the plugin is attached and opens the device when it appears"
           ]

    assert NodeTask.device_warnings(sensor: "temp") == []
  end

  test "the attach hint without TLS" do
    assert NodeTask.attach_hint(:tartarus, :n1@vm, nil) == [
             "attach with: iex --sname me --cookie tartarus --remsh n1@vm"
           ]
  end

  test "the attach hint over TLS carries the shell's TLS flags", %{tmp_dir: dir} do
    [note, hint] = NodeTask.attach_hint(:tartarus, :n1@vm, dir)
    assert note =~ "me.ssl_dist.conf is missing"
    assert note =~ "mix tartarus.gen.certs --nodes n1,me --out #{dir}"

    flags = Enum.join(Tartarus.Security.TLSDist.erl_flags("me", dir), " ")

    assert hint ==
             ~s(attach with: iex --sname me --cookie tartarus --erl "#{flags}" --remsh n1@vm)

    assert hint =~
             "-proto_dist tartarus_tls -ssl_dist_optfile #{Path.join(dir, "me.ssl_dist.conf")}"

    File.write!(Path.join(dir, "me.ssl_dist.conf"), "")
    assert [^hint] = NodeTask.attach_hint(:tartarus, :n1@vm, dir)
  end

  test "--tls-certs: a missing option file, a VM not started over TLS, one that is", %{
    tmp_dir: dir
  } do
    opts = [name: "n1", tls_certs: dir]
    argv = ["--name", "n1", "--host", "h1", "--tls-certs", dir]

    assert NodeTask.tls_check!([name: "n1"], [], :error) == :ok

    error = assert_raise Mix.Error, fn -> NodeTask.tls_check!(opts, argv, :error) end
    assert error.message =~ "n1.ssl_dist.conf not found"
    assert error.message =~ "mix tartarus.gen.certs --nodes n1,me --out #{dir}"

    File.write!(Path.join(dir, "n1.ssl_dist.conf"), "")
    error = assert_raise Mix.Error, fn -> NodeTask.tls_check!(opts, argv, :error) end
    flags = Enum.join(Tartarus.Security.TLSDist.erl_flags("n1", dir), " ")

    assert error.message =~
             ~s(ELIXIR_ERL_OPTIONS="-connect_all false #{flags}" mix tartarus.node --name n1 --host h1 --tls-certs #{dir})

    assert NodeTask.tls_check!(opts, argv, {:ok, [[~c"tartarus_tls"]]}) == :ok
  end
end
