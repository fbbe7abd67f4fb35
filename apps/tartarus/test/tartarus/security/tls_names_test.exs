defmodule Tartarus.Security.TLSNamesTest do
  # Which node names a certificate lets its holder use under `-proto_dist tartarus_tls`.
  use ExUnit.Case, async: true

  alias Tartarus.Security.Certs

  setup_all do
    %{ca: Certs.generate_ca(days: 1)}
  end

  defp names(ca, node_name, hosts) do
    %{cert: der} = Certs.issue(ca, node_name, hosts: hosts, days: 1)
    der |> :public_key.pkix_decode_cert(:otp) |> :tartarus_tls_dist.cert_names()
  end

  test "a CN without a host allows that name on every host the certificate lists", %{ca: ca} do
    assert names(ca, "b", ["pi1", "localhost"]) == [~c"b@pi1", ~c"b@localhost"]
  end

  test "IP addresses in the certificate count as hosts", %{ca: ca} do
    assert names(ca, "b", ["10.0.0.7"]) == [~c"b@10.0.0.7"]
  end

  test "a CN that is a whole node name allows exactly that name", %{ca: ca} do
    assert names(ca, "b@pi1", ["localhost"]) == [~c"b@pi1"]
  end

  test "the names are the certificate's, never another node's", %{ca: ca} do
    refute ~c"evil@pi1" in names(ca, "b", ["pi1"])
    refute ~c"b2@pi1" in names(ca, "b", ["pi1"])
  end
end
