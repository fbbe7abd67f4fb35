defmodule TartarusNode.OperatorTest do
  # The operator's certificate is checked on the operator's side before anything is
  # dialled: each refusal is one line naming the cause (the release test drives the
  # commands themselves against a running TLS node).
  use ExUnit.Case, async: true

  alias TartarusNode.{Config, Operator}

  @moduletag :tmp_dir

  defp config(certs, extra) do
    {:ok, c} = Config.check(node: "tt41@127.0.0.1", tls: [dir: certs] ++ extra, cookie: "c")

    c
  end

  defp certs(dir, name, nodes, hosts) do
    path = Path.join(dir, name)
    {:ok, _} = Tartarus.Security.Certs.generate(path, nodes: nodes, hosts: hosts)
    path
  end

  test "a good operator certificate: its name at the node host, an option file, the client flags",
       %{tmp_dir: dir} do
    certs = certs(dir, "good", ["tt41@127.0.0.1", "op41"], ["127.0.0.1"])
    c = config(certs, operator: "op41")
    tmp = Path.join(dir, "tmp")

    assert {:ok, op} = Operator.check(c, tmp)
    assert op.name == "op41@127.0.0.1"
    assert {:ok, [terms]} = :file.consult(op.optfile)
    assert terms[:client][:certfile] == ~c"#{certs}/op41.pem"
    assert terms[:server][:fail_if_no_peer_cert]

    shell = Operator.shell(c, op, "rpc")
    assert shell =~ "TARTARUS_OPERATOR='op41@127.0.0.1'\n"
    assert shell =~ "-ssl_dist_optfile #{op.optfile}"
  end

  test "refusals name the cause in one line", %{tmp_dir: dir} do
    certs = certs(dir, "node", ["tt41@127.0.0.1", "op41"], ["127.0.0.1"])
    tmp = Path.join(dir, "tmp")

    # No certificate under that name.
    assert {:error, line} = Operator.check(config(certs, operator: "nobody"), tmp)
    assert line =~ "refused before connecting: no operator certificate #{certs}/nobody.pem"

    # Issued by the node's CA for another host: it does not name op41far@127.0.0.1.
    {:ok, _} = Tartarus.Security.Certs.generate(certs, nodes: ["op41far"], hosts: ["198.18.41.1"])

    assert {:error, line} = Operator.check(config(certs, operator: "op41far"), tmp)
    assert line =~ "op41far.pem names op41far@198.18.41.1"
    assert line =~ "not op41far@127.0.0.1"

    # Issued by another CA.
    other = certs(dir, "other", ["op41x"], ["127.0.0.1"])
    File.cp!(Path.join(other, "op41x.pem"), Path.join(certs, "op41x.pem"))
    File.cp!(Path.join(other, "op41x.key"), Path.join(certs, "op41x.key"))
    assert {:error, line} = Operator.check(config(certs, operator: "op41x"), tmp)
    assert line =~ "op41x.pem was not issued by this node's CA #{certs}/ca.pem"

    for {:error, l} <- [Operator.check(config(certs, operator: "op41x"), tmp)],
        do: refute(l =~ "\n")
  end
end
