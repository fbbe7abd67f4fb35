defmodule Tartarus.Security.TLSDialingTest do
  # The dialing side of `-proto_dist tartarus_tls`: the TLS client's certificate check
  # (`:tartarus_tls_dist.verify_server/4`) and the options that install it. The handshake with
  # real nodes is in tls_dist_peer_test.exs.
  #
  # Not async: the client options tests set the kernel's `inet_dist_connect_options`.
  use ExUnit.Case, async: false

  alias Tartarus.Security.Certs

  setup_all do
    ca = Certs.generate_ca(days: 1)
    %{cert: der} = Certs.issue(ca, "b", hosts: ["pi1"], days: 1)
    %{der: der, cert: :public_key.pkix_decode_cert(der, :otp)}
  end

  defp default, do: {&:tartarus_tls_dist.default_verify/3, []}

  describe "verify_server/4" do
    test "the server's certificate must name the node dialled", %{cert: cert, der: der} do
      assert {:valid, {:b@pi1, _}} =
               :tartarus_tls_dist.verify_server(cert, der, :valid_peer, {:b@pi1, default()})

      assert {:fail, {:bad_cert, {:node_not_named, :evil@pi1}}} =
               :tartarus_tls_dist.verify_server(cert, der, :valid_peer, {:evil@pi1, default()})

      # Right name, host the certificate does not list.
      assert {:fail, {:bad_cert, {:node_not_named, :b@pi2}}} =
               :tartarus_tls_dist.verify_server(cert, der, :valid_peer, {:b@pi2, default()})
    end

    test "the CA certificates of the chain are not checked for the name", %{cert: cert, der: der} do
      assert {:valid, _} =
               :tartarus_tls_dist.verify_server(cert, der, :valid, {:evil@pi1, default()})
    end

    test "every failure of the usual checks still fails", %{cert: cert, der: der} do
      for reason <- [:unknown_ca, :cert_expired, :hostname_check_failed] do
        assert {:fail, {:bad_cert, ^reason}} =
                 :tartarus_tls_dist.verify_server(
                   cert,
                   der,
                   {:bad_cert, reason},
                   {:b@pi1, default()}
                 )
      end
    end

    test "a verify_fun of the options runs first, with its own state", %{cert: cert, der: der} do
      refuse = fn _cert, _event, state -> {:fail, {:refused_by_own_fun, state}} end

      assert {:fail, {:refused_by_own_fun, :s}} =
               :tartarus_tls_dist.verify_server(cert, der, :valid_peer, {:b@pi1, {refuse, :s}})

      # One that accepts the host name failure is still held to the node name.
      lenient = fn
        _cert, {:bad_cert, :hostname_check_failed}, n -> {:valid, n + 1}
        _cert, _event, n -> {:valid, n + 1}
      end

      assert {:valid, {:b@pi1, {^lenient, 1}}} =
               :tartarus_tls_dist.verify_server(
                 cert,
                 der,
                 {:bad_cert, :hostname_check_failed},
                 {:b@pi1, {lenient, 0}}
               )

      assert {:fail, {:bad_cert, {:node_not_named, :evil@pi1}}} =
               :tartarus_tls_dist.verify_server(
                 cert,
                 der,
                 {:bad_cert, :hostname_check_failed},
                 {:evil@pi1, {lenient, 0}}
               )

      # A fun of arity 4 gets the DER certificate too.
      with_der = fn _cert, got, _event, state -> {:valid, [got | state]} end

      assert {:valid, {:b@pi1, {_, [^der]}}} =
               :tartarus_tls_dist.verify_server(cert, der, :valid_peer, {:b@pi1, {with_der, []}})
    end
  end

  describe "client_options/1" do
    setup do
      previous = Application.fetch_env(:kernel, :inet_dist_connect_options)

      on_exit(fn ->
        case previous do
          {:ok, value} -> Application.put_env(:kernel, :inet_dist_connect_options, value)
          :error -> Application.delete_env(:kernel, :inet_dist_connect_options)
        end
      end)
    end

    test "put a verify_fun bound to the node dialled in the options" do
      Application.put_env(:kernel, :inet_dist_connect_options, verify: :verify_peer)

      assert {:ok, opts} = :tartarus_tls_dist.client_options(:b@pi1)
      assert {fun, {:b@pi1, {inner, []}}} = opts[:verify_fun]
      assert fun == (&:tartarus_tls_dist.verify_server/4)
      assert inner == (&:tartarus_tls_dist.default_verify/3)
      assert opts[:verify] == :verify_peer
    end

    test "wrap the options' own verify_fun" do
      own = {&:tartarus_tls_dist.default_verify/3, :own_state}

      Application.put_env(:kernel, :inet_dist_connect_options,
        verify: :verify_peer,
        verify_fun: own
      )

      assert {:ok, opts} = :tartarus_tls_dist.client_options(:b@pi1)
      assert [{_, {:b@pi1, ^own}}] = for({:verify_fun, v} <- opts, do: v)
    end

    test "refuse to dial without verify_peer, or with a verify_fun it cannot wrap" do
      Application.put_env(:kernel, :inet_dist_connect_options, verify: :verify_none)

      assert :tartarus_tls_dist.client_options(:b@pi1) ==
               {:error, {:verify_peer_needed, {:verify, :verify_none}}}

      Application.put_env(:kernel, :inet_dist_connect_options,
        verify: :verify_peer,
        verify_fun: fn _errors -> true end
      )

      assert {:error, {:verify_fun_not_wrappable, _}} = :tartarus_tls_dist.client_options(:b@pi1)
    end
  end
end
