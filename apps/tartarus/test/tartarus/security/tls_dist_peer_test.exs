defmodule Tartarus.Security.TLSDistPeerTest do
  # Real BEAM nodes over TLS distribution with mutual certificate authentication.
  #
  # The test node itself is not distributed. It starts three peers with OTP's :peer and
  # `connection: :standard_io`, so it controls them over their stdin/stdout (a control
  # connection that needs no distribution) while the peers use TLS distribution among
  # themselves:
  #
  #   * A and B hold certificates from our CA: A connects to B and :erpc works;
  #   * C holds a certificate from a foreign CA. It trusts our CA, so the refusal of C -> A is
  #     A's own (as TLS server, `verify_peer` + `fail_if_no_peer_cert`); A -> C is refused by
  #     A as TLS client. C never shows up in A's nodes().
  #   * EVIL holds B's certificate and key (stolen) under another node name: A refuses it
  #     whichever side dials (names are bound to certificates, see :tartarus_tls_dist), and
  #     the legitimate B still connects. When A dials EVIL, A's TLS handshake fails, so EVIL
  #     never sees A up and an RPC it would run on A's nodeup never runs.
  #
  # Certificates name the nodes (CN = the node name before the `@`), so the names are fixed
  # for the module: tls_<role>_<suffix>.
  # All peers use the same cookie, so every refusal is TLS's, not the cookie's.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport

  alias Tartarus.Security.{Certs, TLSDist}

  @moduletag :peer
  @moduletag timeout: 120_000

  @cookie "tartarus_tls_test"

  # Loaded into EVIL (which runs no Elixir, so Erlang calls only): on every nodeup of `victim`
  # it runs `:os.cmd('touch <dir>/pwned_<n>')` there, the attack of issue 32, and logs it.
  {:module, impostor, impostor_beam, _} =
    defmodule Impostor do
      def start(victim, dir) do
        parent = self()

        pid =
          :erlang.spawn(fn ->
            :ok = :net_kernel.monitor_nodes(true)
            send(parent, :ready)
            loop(victim, dir, 0, [])
          end)

        :erlang.register(:tartarus_test_impostor, pid)

        receive do
          :ready -> :ok
        end
      end

      # What happened so far, oldest first; answered after any RPC under way has ended.
      def log do
        send(:tartarus_test_impostor, {:log, self()})

        receive do
          {:log, log} -> log
        after
          10_000 -> :no_answer
        end
      end

      defp loop(victim, dir, n, log) do
        receive do
          {:nodeup, ^victim} ->
            marker = dir ++ ~c"/pwned_" ++ :erlang.integer_to_list(n)

            result =
              try do
                :erpc.call(victim, :os, :cmd, [~c"touch " ++ marker])
              catch
                kind, reason -> {kind, reason}
              end

            loop(victim, dir, n + 1, [{:nodeup, {:rpc, result}} | log])

          {:nodedown, ^victim} ->
            loop(victim, dir, n, [:nodedown | log])

          {:log, from} ->
            send(from, {:log, :lists.reverse(log)})
            loop(victim, dir, n, log)
        end
      end
    end

  @impostor impostor
  @impostor_beam impostor_beam

  setup_all do
    epmd =
      System.find_executable("epmd") ||
        raise "the :peer tests need epmd (part of OTP) on the PATH to start named nodes; not found"

    {_, 0} = System.cmd(epmd, ["-daemon"])

    dir = Path.join(System.tmp_dir!(), "tartarus_tls_#{System.unique_integer([:positive])}")
    ours = Path.join(dir, "ours")
    foreign = Path.join(dir, "foreign")

    suffix = System.unique_integer([:positive])
    names = Map.new([:a, :b, :c, :d, :evil], &{&1, "tls_#{&1}_#{suffix}"})
    {:ok, _} = Certs.generate(ours, nodes: [names.a, names.b, names.d], days: 1)
    {:ok, _} = Certs.generate(foreign, nodes: [names.c], days: 1)

    # C: a foreign certificate, but it trusts our CA (so only A can refuse it).
    trust_ours = String.to_charlist(Path.join(ours, "ca.pem"))

    terms =
      for {side, opts} <- TLSDist.optfile_terms(names.c, foreign),
          do: {side, Keyword.put(opts, :cacertfile, trust_ours)}

    File.write!(TLSDist.optfile_path(names.c, foreign), :io_lib.format(~c"~tp.~n", [terms]))

    on_exit(fn -> File.rm_rf!(dir) end)
    %{ours: ours, foreign: foreign, names: names}
  end

  setup %{ours: ours, foreign: foreign, names: names} do
    # EVIL starts under its own name with B's certificate and key.
    roles = [a: {names.a, ours}, b: {names.b, ours}, c: {names.c, foreign}, evil: {names.b, ours}]

    peers =
      for {role, {cert_name, certs}} <- roles, into: %{} do
        {:ok, pid, node} =
          :peer.start(%{
            name: String.to_atom(names[role]),
            args: peer_args(cert_name, certs),
            connection: :standard_io
          })

        {role, %{pid: pid, node: node}}
      end

    on_exit(fn ->
      for {_role, %{pid: pid}} <- peers, Process.alive?(pid), do: :peer.stop(pid)

      for {_role, %{pid: pid, node: node}} <- peers do
        refute Process.alive?(pid), "peer #{node} is still running"
        # A stopped peer leaves epmd when its VM exits, a moment after :peer.stop/1 returns.
        eventually(fn -> not registered?(node) end)
      end
    end)

    %{peers: peers}
  end

  test "nodes with certificates from our CA connect over TLS; a foreign certificate is refused",
       %{peers: %{a: a, b: b, c: c}} do
    # Every peer really runs TLS distribution.
    for %{pid: pid} <- [a, b, c] do
      assert {:ok, [[~c"tartarus_tls"]]} = :peer.call(pid, :init, :get_argument, [:proto_dist])
      assert :peer.call(pid, :erlang, :nodes, []) == []
    end

    # A <-> B: mutual authentication succeeds, and :erpc works across.
    assert :peer.call(a.pid, :net_kernel, :connect_node, [b.node]) == true
    assert :peer.call(a.pid, :erpc, :call, [b.node, :erlang, :node, []]) == b.node
    assert :peer.call(b.pid, :erlang, :nodes, []) == [a.node]

    # C -> A: A (TLS server) refuses C's foreign certificate.
    assert :peer.call(c.pid, :net_kernel, :connect_node, [a.node]) == false
    # A -> C: A (TLS client) refuses C's certificate too.
    assert :peer.call(a.pid, :net_kernel, :connect_node, [c.node]) == false

    assert :peer.call(a.pid, :erlang, :nodes, []) == [b.node]
    assert :peer.call(c.pid, :erlang, :nodes, []) == []

    assert {:badrpc, _} = :peer.call(c.pid, :rpc, :call, [a.node, :erlang, :node, []])
  end

  test "a stolen certificate under another node name is refused; its owner still connects",
       %{peers: %{a: a, b: b, evil: evil}} do
    assert {:ok, [[~c"tartarus_tls"]]} = :peer.call(evil.pid, :init, :get_argument, [:proto_dist])

    # EVIL -> A: A (accepting) allows only the names B's certificate names.
    assert :peer.call(evil.pid, :net_kernel, :connect_node, [a.node]) == false
    assert :peer.call(a.pid, :erlang, :nodes, []) == []
    assert {:badrpc, _} = :peer.call(evil.pid, :rpc, :call, [a.node, :erlang, :node, []])

    # A -> EVIL: A (dialing) refuses it in the TLS handshake.
    assert :peer.call(a.pid, :net_kernel, :connect_node, [evil.node]) == false
    assert :peer.call(a.pid, :erlang, :nodes, []) == []
    assert :peer.call(evil.pid, :erlang, :nodes, []) == []

    # The legitimate B connects, both ways, and :erpc works.
    assert :peer.call(b.pid, :net_kernel, :connect_node, [a.node]) == true
    assert :peer.call(b.pid, :erpc, :call, [a.node, :erlang, :node, []]) == a.node
    assert :peer.call(a.pid, :erlang, :nodes, []) == [b.node]
    assert :peer.call(a.pid, :erlang, :disconnect_node, [b.node]) == true
    assert eventually(fn -> :peer.call(a.pid, :erlang, :nodes, []) == [] end)
    assert :peer.call(a.pid, :net_kernel, :connect_node, [b.node]) == true
    assert :peer.call(a.pid, :erlang, :nodes, []) == [b.node]
  end

  test "an impostor that is dialled gets nothing through: its RPC on nodeup never runs (10 tries)",
       %{peers: %{a: a, b: b, evil: evil}, ours: ours} do
    markers = Path.join(ours, "markers_#{System.unique_integer([:positive])}")
    File.mkdir_p!(markers)

    assert {:module, @impostor} =
             :peer.call(evil.pid, :code, :load_binary, [
               @impostor,
               ~c"impostor.beam",
               @impostor_beam
             ])

    assert :peer.call(evil.pid, @impostor, :start, [a.node, String.to_charlist(markers)]) == :ok

    # A logs each refusal as an error; ten of them are expected here.
    :ok = :peer.call(a.pid, :logger, :set_primary_config, [:level, :critical])

    results =
      for _try <- 1..10 do
        # (A long call timeout: a dial that does connect can take a while to settle.)
        result = :peer.call(a.pid, :net_kernel, :connect_node, [evil.node], 60_000)
        # The attempt is over once A has no connection to EVIL (any connection that came up
        # has been closed again).
        assert eventually(fn -> evil.node not in :peer.call(a.pid, :erlang, :nodes, []) end)
        result
      end

    log = :peer.call(evil.pid, @impostor, :log, [])
    ran = File.ls!(markers)

    assert ran == [],
           "the impostor's RPC ran on A in #{length(ran)} of 10 tries (impostor's log: #{inspect(log)})"

    assert log == [], "the impostor saw A come up: #{inspect(log)}"
    assert results == List.duplicate(false, 10)
    assert :peer.call(a.pid, :erlang, :nodes, []) == []

    # A still dials the real B.
    assert :peer.call(a.pid, :net_kernel, :connect_node, [b.node]) == true
    assert :peer.call(a.pid, :erpc, :call, [b.node, :erlang, :node, []]) == b.node
  end

  test "options given as -ssl_dist_opt arguments: the dialing side checks names too",
       %{peers: %{b: b, evil: evil}, ours: ours, names: names} do
    file = &Path.join(ours, &1)

    opts =
      for side <- ["server", "client"],
          {key, value} <- [
            certfile: file.("#{names.d}.pem"),
            keyfile: file.("#{names.d}.key"),
            cacertfile: file.("ca.pem"),
            verify: "verify_peer"
          ],
          do: ["#{side}_#{key}", value]

    args =
      ["-setcookie", @cookie, "-kernel", "logger_level", "critical", "-proto_dist"] ++
        ["tartarus_tls", "-ssl_dist_opt"] ++
        List.flatten(opts) ++
        ["server_fail_if_no_peer_cert", "true"] ++
        Enum.drop(TLSDist.erl_flags(names.d, ours), 4)

    {:ok, pid, _node} =
      :peer.start(%{
        name: String.to_atom(names.d),
        args: Enum.map(args, &String.to_charlist/1),
        connection: :standard_io
      })

    try do
      assert :peer.call(pid, :init, :get_argument, [:ssl_dist_optfile]) == :error
      assert :peer.call(pid, :net_kernel, :connect_node, [b.node]) == true
      assert :peer.call(pid, :erpc, :call, [b.node, :erlang, :node, []]) == b.node
      assert :peer.call(pid, :net_kernel, :connect_node, [evil.node]) == false
      assert :peer.call(pid, :erlang, :nodes, []) == [b.node]
    after
      :peer.stop(pid)
    end
  end

  defp peer_args(name, certs) do
    # `logger_level error` keeps the peers' TLS alert notices out of the test output.
    (["-setcookie", @cookie, "-kernel", "logger_level", "error"] ++ TLSDist.erl_flags(name, certs))
    |> Enum.map(&String.to_charlist/1)
  end

  defp registered?(node) do
    [name, _host] = node |> Atom.to_string() |> String.split("@")
    {:ok, names} = :erl_epmd.names()
    Enum.any?(names, fn {n, _port} -> List.to_string(n) == name end)
  end
end
