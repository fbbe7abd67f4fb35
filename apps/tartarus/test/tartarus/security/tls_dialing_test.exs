defmodule Tartarus.Security.TLSDialingTest do
  # The dialing side of `-proto_dist tartarus_tls`: the TLS client's certificate check
  # (`:tartarus_tls_dist.verify_server/4`) and the options that install it. The handshake with
  # real nodes is in tls_dist_peer_test.exs.
  #
  # Not async: the client options tests set the kernel's `inet_dist_connect_options`.
  use ExUnit.Case, async: false

  alias Tartarus.Security.Certs

  doctest :tartarus_tls_dist

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

  describe "refusal/4: why the node dialled refused, in one line" do
    @tag :tmp_dir
    test "the names the certificate names, when the node does not admit this name", %{
      tmp_dir: dir
    } do
      {:ok, _} = Certs.generate(dir, nodes: ["me"], hosts: ["pi1", "10.0.0.9"])
      opts = [certfile: ~c"#{dir}/me.pem", cacertfile: ~c"#{dir}/ca.pem"]
      why = &:tartarus_tls_dist.refusal(:n@pi1, &1, {:recv_status_failed, :not_allowed}, opts)

      assert List.to_string(why.(:you@pi1)) ==
               "tartarus_tls: no connection from you@pi1 to n@pi1: the node admits only the names this node's certificate #{dir}/me.pem names (me@pi1, me@10.0.0.9), and this node runs as you@pi1"

      # A name the certificate does name: then only the node's allowed list can refuse it.
      assert List.to_string(why.(:me@pi1)) =~
               "the node's allowed list (net_kernel:allow/1) leaves this name out"
    end

    test "TLS alerts: the node's (it refused our certificate) and ours (we refused its)" do
      opts = [certfile: ~c"/c/me.pem", cacertfile: ~c"/c/ca.pem"]

      alert = fn kind, text ->
        {:ssl_connect_failed, {10, 0, 0, 1}, 4370, {:error, {:tls_alert, {kind, text}}}}
      end

      why = &List.to_string(:tartarus_tls_dist.refusal(:n@pi1, :me@pi1, &1, opts))

      assert why.(
               alert.(
                 :unknown_ca,
                 ~c"TLS client: In state cipher received SERVER ALERT: Fatal - Unknown CA"
               )
             ) =~
               "me@pi1 to n@pi1: this node's certificate /c/me.pem was not issued by the node's CA (TLS alert unknown_ca from the node)"

      assert why.(
               alert.(
                 :certificate_expired,
                 ~c"received SERVER ALERT: Fatal - Certificate Expired"
               )
             ) =~
               "this node's certificate /c/me.pem has expired, by the node's clock"

      assert why.(alert.(:unknown_ca, ~c"TLS client: generated CLIENT ALERT: Fatal - Unknown CA")) =~
               "the node's certificate was not issued by the CA this node trusts (/c/ca.pem)"

      assert why.(
               alert.(
                 :bad_certificate,
                 ~c"generated CLIENT ALERT: Fatal - Bad Certificate\n {bad_cert,{node_not_named,n@pi1}}"
               )
             ) =~
               "the node's certificate does not name the node dialled"

      assert why.({:recv_challenge_ack_failed, {:error, :closed}}) =~ "another cookie"
    end

    test "what is no refusal says nothing (the node is down, unreachable, the link lost)" do
      for reason <- [
            {:ssl_connect_failed, {10, 0, 0, 1}, 4370, {:error, :econnrefused}},
            {:ssl_connect_failed, {10, 0, 0, 1}, 4370, {:error, :timeout}},
            {:recv_status_failed, {:error, :closed}},
            :connection_closed,
            :net_tick_timeout
          ] do
        assert :tartarus_tls_dist.refusal(:n@pi1, :me@pi1, reason, []) == :none
      end
    end
  end
end
