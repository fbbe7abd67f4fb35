defmodule Tartarus.Security.CertsTest do
  use ExUnit.Case, async: true

  alias Tartarus.Security.{Certs, TLSDist}

  doctest Certs
  doctest TLSDist

  setup do
    dir = Path.join(System.tmp_dir!(), "tartarus_certs_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    %{dir: dir}
  end

  test "generate writes a CA, node certificates that chain to it, and option files", %{dir: dir} do
    assert {:ok, %{ca: ca_path, ca_created?: true, nodes: ["a", "b@host1"]}} =
             Certs.generate(dir,
               nodes: ["a", "b@host1"],
               days: 10,
               hosts: ["localhost", "10.0.0.7"]
             )

    for name <- ["ca", "a", "b@host1"] do
      assert File.exists?(Path.join(dir, name <> ".pem"))
      assert Bitwise.band(File.stat!(Path.join(dir, name <> ".key")).mode, 0o777) == 0o600
    end

    [{:Certificate, ca_der, _}] = ca_path |> File.read!() |> :public_key.pem_decode()

    for name <- ["a", "b@host1"] do
      [{:Certificate, der, _}] =
        dir |> Path.join(name <> ".pem") |> File.read!() |> :public_key.pem_decode()

      assert {:ok, _} = :public_key.pkix_path_validation(ca_der, [der], [])

      [key_entry] = dir |> Path.join(name <> ".key") |> File.read!() |> :public_key.pem_decode()
      key = :public_key.pem_entry_decode(key_entry)
      signature = :public_key.sign("msg", :sha256, key)

      # ECPrivateKey record: {_, version, private, curve, public_point, attributes}
      public = {{:ECPoint, elem(key, 4)}, elem(key, 3)}

      assert :public_key.verify("msg", :sha256, signature, public)
    end

    [{:Certificate, b_der, _}] =
      dir |> Path.join("b@host1.pem") |> File.read!() |> :public_key.pem_decode()

    assert :public_key.pkix_verify_hostname(b_der, dns_id: ~c"host1")
    assert :public_key.pkix_verify_hostname(b_der, ip: {10, 0, 0, 7})
    refute :public_key.pkix_verify_hostname(b_der, dns_id: ~c"elsewhere")

    assert {:ok, [terms]} = :file.consult(TLSDist.optfile_path("a", dir))
    assert terms == TLSDist.optfile_terms("a", dir)
    assert terms[:server][:verify] == :verify_peer
    assert terms[:server][:fail_if_no_peer_cert] == true
    assert terms[:client][:verify] == :verify_peer
    assert terms[:client][:cacertfile] == String.to_charlist(Path.join(dir, "ca.pem"))
  end

  test "an existing CA is reused, so nodes can be added later", %{dir: dir} do
    {:ok, _} = Certs.generate(dir, nodes: ["a"])
    ca_pem = File.read!(Path.join(dir, "ca.pem"))

    assert {:ok, %{ca_created?: false}} = Certs.generate(dir, nodes: ["c"])
    assert File.read!(Path.join(dir, "ca.pem")) == ca_pem

    {:ok, ca} = Certs.load_ca(dir)

    [{:Certificate, c_der, _}] =
      dir |> Path.join("c.pem") |> File.read!() |> :public_key.pem_decode()

    assert {:ok, _} = :public_key.pkix_path_validation(ca.cert, [c_der], [])
  end

  test "a certificate from another CA does not validate", %{dir: dir} do
    ours = Certs.generate_ca()
    theirs = Certs.generate_ca(name: "Foreign CA")
    foreign = Certs.issue(theirs, "c")

    assert {:error, {:bad_cert, _}} =
             :public_key.pkix_path_validation(ours.cert, [foreign.cert], [])

    refute File.exists?(dir)
  end

  test "bad input is refused with a clear error", %{dir: dir} do
    assert Certs.generate(dir, nodes: ["ok", "../etc/passwd"]) ==
             {:error,
              "invalid node names: expected letters, digits, _ and -, optionally @host, got: \"../etc/passwd\""}

    assert Certs.generate(dir, nodes: ["a"], days: 0) ==
             {:error, "invalid option :days: expected a positive integer, got: 0"}

    assert Certs.generate(dir, nodes: ["a"], hosts: ["bad host"]) ==
             {:error,
              "invalid option :hosts: expected host names or IP addresses, got: \"bad host\""}

    File.mkdir_p!(dir)
    File.write!(Path.join(dir, "ca.pem"), "junk")
    File.write!(Path.join(dir, "ca.key"), "junk")

    assert Certs.generate(dir, nodes: ["a"]) ==
             {:error,
              "invalid CA in #{dir}: expected ca.pem with one certificate and ca.key with one EC private key"}
  end

  # The mix task tartarus.gen.certs is tested with the tooling (apps/tartarus_tools).
end
