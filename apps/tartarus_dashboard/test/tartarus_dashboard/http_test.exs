defmodule TartarusDashboard.HttpTest do
  # The dashboard's door, over raw sockets: the token, the Host and the Origin are checked
  # before any body is read; bodies are read with the limit whatever the framing; slow and
  # idle connections are closed; connections per client and in all are bounded.
  use ExUnit.Case, async: false

  import Tartarus.TestSupport
  alias Tartarus.JSON

  @token "test-token-0123456789"

  setup do
    h = :"door_#{System.unique_integer([:positive])}"
    {:ok, _} = Tartarus.start_host(h)
    on_exit(fn -> Tartarus.stop_host(h) end)
    %{host: to_string(h)}
  end

  defp start(opts) do
    {:ok, dash} = TartarusDashboard.start_link([token: @token, max_body: 1_024] ++ opts)
    dash
  end

  # From 127.0.0.1, or another loopback address (a client of its own for the server).
  defp connect(dash, from \\ {127, 0, 0, 1}) do
    {:ok, sock} =
      :gen_tcp.connect(~c"127.0.0.1", TartarusDashboard.port(dash), [
        :binary,
        active: false,
        ip: from
      ])

    sock
  end

  defp host(dash), do: "127.0.0.1:#{TartarusDashboard.port(dash)}"

  # One answer: {status, headers (lower-case names), body}; reads exactly its length.
  defp answer(sock) do
    {head, rest} = read_head(sock, "")
    [status_line | lines] = String.split(head, "\r\n")
    ["HTTP/1.1", code | _] = String.split(status_line, " ")

    headers =
      Map.new(lines, fn l ->
        [k, v] = String.split(l, ":", parts: 2)
        {String.downcase(k), String.trim(v)}
      end)

    length = String.to_integer(headers["content-length"] || "0")
    body = read_n(sock, rest, length)
    body = if headers["content-type"] =~ "json", do: JSON.decode!(body), else: body
    {String.to_integer(code), headers, body}
  end

  defp read_head(sock, acc) do
    case :binary.split(acc, "\r\n\r\n") do
      [head, rest] ->
        {head, rest}

      [_] ->
        {:ok, more} = :gen_tcp.recv(sock, 0, 5_000)
        read_head(sock, acc <> more)
    end
  end

  defp read_n(_sock, acc, n) when byte_size(acc) >= n, do: acc

  defp read_n(sock, acc, n) do
    {:ok, more} = :gen_tcp.recv(sock, 0, 5_000)
    read_n(sock, acc <> more, n)
  end

  # The server closed its side: the next read says so (no more data).
  defp closed?(sock), do: :gen_tcp.recv(sock, 0, 5_000) == {:error, :closed}

  defp chunk(data), do: [Integer.to_string(byte_size(data), 16), "\r\n", data, "\r\n"]

  describe "the token before the body" do
    test "a chunked POST without the token gets 401 after its headers alone, then the close" do
      dash = start([])
      sock = connect(dash)

      :ok =
        :gen_tcp.send(sock, [
          "POST /api/agents HTTP/1.1\r\nHost: #{host(dash)}\r\n",
          "Content-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n",
          chunk(String.duplicate("x", 4_096))
        ])

      # The body is not finished (no last chunk) and never will be: the answer comes anyway.
      assert {401, h, %{"error" => "token_required"}} = answer(sock)
      assert h["connection"] == "close"
      assert closed?(sock)
    end

    test "a declared 100 MB body without the token, or with a wrong one, is refused at once" do
      dash = start([])

      for {auth, status} <- [{"", 401}, {"Authorization: Bearer wrong-token-1\r\n", 403}] do
        sock = connect(dash)

        :ok =
          :gen_tcp.send(
            sock,
            "POST /api/agents HTTP/1.1\r\nHost: #{host(dash)}\r\n#{auth}Content-Length: 104857600\r\n\r\n"
          )

        assert {^status, _, _} = answer(sock)
        assert closed?(sock)
      end
    end

    test "a 100 MB chunked POST without the token leaves the node's memory as it was" do
      dash = start([])
      sock = connect(dash)
      :erlang.garbage_collect()
      before = :erlang.memory(:total)
      me = self()
      sampler = spawn_link(fn -> sample(me, before) end)

      :ok =
        :gen_tcp.send(
          sock,
          "POST /api/agents HTTP/1.1\r\nHost: #{host(dash)}\r\nTransfer-Encoding: chunked\r\n\r\n"
        )

      mb = chunk(:binary.copy("x", 1_048_576))

      sent =
        Enum.reduce_while(1..100, 0, fn _, n ->
          if :gen_tcp.send(sock, mb) == :ok, do: {:cont, n + 1}, else: {:halt, n}
        end)

      _ = :gen_tcp.send(sock, "0\r\n\r\n")

      answer =
        case :gen_tcp.recv(sock, 0, 5_000) do
          {:ok, data} -> data
          {:error, reason} -> reason
        end

      send(sampler, {:stop, self()})

      peak =
        receive do
          {:peak, p} -> p
        end

      # The answer is 401 (or, when the server closed while 100 MB were still coming, the
      # connection was reset): never a body read to its end.
      assert (is_binary(answer) and answer =~ "HTTP/1.1 401") or answer in [:econnreset, :closed]
      assert sent < 100
      assert peak - before < 50 * 1_048_576
    end
  end

  defp sample(parent, peak) do
    receive do
      {:stop, ^parent} -> send(parent, {:peak, max(peak, :erlang.memory(:total))})
    after
      5 -> sample(parent, max(peak, :erlang.memory(:total)))
    end
  end

  describe "bodies have a limit, whatever the framing" do
    test "a chunked body is refused with 413 as soon as it goes over max_body, then the close" do
      dash = start([])
      sock = connect(dash)

      :ok =
        :gen_tcp.send(sock, [
          "POST /api/agents HTTP/1.1\r\nHost: #{host(dash)}\r\nAuthorization: Bearer #{@token}\r\n",
          "Transfer-Encoding: chunked\r\n\r\n",
          for(_ <- 1..3, do: chunk(String.duplicate("x", 500)))
        ])

      assert {413, _, %{"error" => "body_too_large", "message" => m}} = answer(sock)
      assert m =~ "at most 1024"
      assert closed?(sock)
    end

    test "a declared length over max_body is refused before the body is sent" do
      dash = start([])
      sock = connect(dash)

      :ok =
        :gen_tcp.send(
          sock,
          "POST /api/agents HTTP/1.1\r\nHost: #{host(dash)}\r\nAuthorization: Bearer #{@token}\r\nContent-Length: 5000\r\n\r\n"
        )

      assert {413, _, %{"error" => "body_too_large", "message" => m}} = answer(sock)
      assert m =~ "5000 bytes; at most 1024"
      assert closed?(sock)
    end

    test "a chunked body within the limit is acted on, and the connection serves the next request",
         c do
      dash = start([])
      sock = connect(dash)
      json = ~s({"host":"#{c.host}","module":"Tartarus.Examples.Echo"})
      {a, b} = String.split_at(json, 10)

      :ok =
        :gen_tcp.send(sock, [
          "POST /api/agents HTTP/1.1\r\nHost: #{host(dash)}\r\nX-Tartarus-Token: #{@token}\r\n",
          "Transfer-Encoding: chunked\r\n\r\n",
          chunk(a),
          String.replace(IO.iodata_to_binary(chunk(b)), "\r\n", ";ext=1\r\n", global: false),
          "0\r\nX-Trailer: yes\r\n\r\n"
        ])

      assert {201, h, %{"ok" => true, "id" => id, "host" => host}} = answer(sock)
      assert host == c.host and h["connection"] == nil
      assert {:ok, _} = Tartarus.whereis({id, String.to_existing_atom(c.host)})

      :ok = :gen_tcp.send(sock, "GET /api/agents/#{id} HTTP/1.1\r\nHost: #{host(dash)}\r\n\r\n")
      assert {200, _, %{"id" => ^id}} = answer(sock)
    end

    test "a client that waits for 100 Continue gets it once the checks passed" do
      dash = start([])
      sock = connect(dash)

      :ok =
        :gen_tcp.send(
          sock,
          "POST /api/agents HTTP/1.1\r\nHost: #{host(dash)}\r\nAuthorization: Bearer #{@token}\r\nContent-Length: 2\r\nExpect: 100-continue\r\n\r\n"
        )

      assert {:ok, "HTTP/1.1 100 Continue\r\n\r\n" <> _} = :gen_tcp.recv(sock, 0, 5_000)
      :ok = :gen_tcp.send(sock, "{}")
      assert {400, _, %{"error" => "missing_param"}} = answer(sock)
    end

    test "malformed framing gets 4xx answers, a line over 8 KiB the close" do
      dash = start([])
      h = host(dash)

      cases = [
        {"POST /api/agents HTTP/1.1\r\nHost: #{h}\r\nContent-Length: 2\r\nTransfer-Encoding: chunked\r\n\r\n",
         400},
        {"POST /api/agents HTTP/1.1\r\nHost: #{h}\r\nTransfer-Encoding: gzip\r\n\r\n", 501},
        {"POST /api/agents HTTP/1.1\r\nHost: #{h}\r\nContent-Length: lots\r\n\r\n", 400},
        {"POST /api/agents HTTP/1.1\r\nHost: #{h}\r\nX-Tartarus-Token: #{@token}\r\nTransfer-Encoding: chunked\r\n\r\nzz\r\n",
         400},
        {"GET / HTTP/1.1\r\nHost: #{h}\r\nHost: #{h}\r\n\r\n", 400}
      ]

      for {request, status} <- cases do
        sock = connect(dash)
        :ok = :gen_tcp.send(sock, request)
        assert {^status, _, %{"error" => _}} = answer(sock), request
        assert closed?(sock)
      end

      # A request line or header line over 8 KiB closes the connection at once, with no
      # answer; the server goes on serving. A chunk line over 8 KiB gets a 400.
      for request <- [
            "GET /#{String.duplicate("a", 10_000)} HTTP/1.1\r\nHost: #{h}\r\n\r\n",
            "GET / HTTP/1.1\r\nHost: #{h}\r\nX-Big: #{String.duplicate("a", 10_000)}\r\n\r\n"
          ] do
        sock = connect(dash)
        :ok = :gen_tcp.send(sock, request)
        assert closed?(sock)
      end

      sock = connect(dash)

      :ok =
        :gen_tcp.send(
          sock,
          "POST /api/agents HTTP/1.1\r\nHost: #{h}\r\nX-Tartarus-Token: #{@token}\r\nTransfer-Encoding: chunked\r\n\r\n1#{String.duplicate(" ", 10_000)}\r\n"
        )

      assert {400, _, %{"message" => m}} = answer(sock)
      assert m =~ "line is longer than 8192 bytes"

      sock = connect(dash)
      :ok = :gen_tcp.send(sock, "GET /api/info HTTP/1.1\r\nHost: #{h}\r\n\r\n")
      assert {200, _, _} = answer(sock)
    end

    test "a request with more than 100 header lines gets 431" do
      dash = start([])
      sock = connect(dash)
      many = for i <- 1..101, do: "X-H#{i}: 1\r\n"

      :ok =
        :gen_tcp.send(sock, ["GET /api/info HTTP/1.1\r\nHost: #{host(dash)}\r\n", many, "\r\n"])

      assert {431, _, %{"error" => "too_many_headers"}} = answer(sock)
      assert closed?(sock)
    end
  end

  describe "Host and Origin" do
    defp get_with(dash, headers) do
      sock = connect(dash)
      :ok = :gen_tcp.send(sock, ["GET /api/info HTTP/1.1\r\n", headers, "\r\n"])
      {status, _, body} = answer(sock)
      :gen_tcp.close(sock)
      {status, body}
    end

    test "a foreign Host (DNS rebinding) or Origin is refused; this dashboard's names are served" do
      dash = start(hosts: ["Dash.Example"])
      port = TartarusDashboard.port(dash)

      assert {403, %{"error" => "bad_host", "message" => m}} =
               get_with(dash, "Host: evil.example:#{port}\r\n")

      assert m =~ "evil.example"
      assert {403, %{"error" => "bad_host"}} = get_with(dash, "Host: 127.0.0.1:#{port + 1}\r\n")
      assert {403, %{"error" => "bad_host"}} = get_with(dash, "Host: 127.0.0.1.evil.example\r\n")
      assert {400, %{"error" => "bad_request"}} = get_with(dash, "")

      assert {403, %{"error" => "bad_origin"}} =
               get_with(
                 dash,
                 "Host: 127.0.0.1:#{port}\r\nOrigin: http://evil.example:#{port}\r\n"
               )

      assert {403, %{"error" => "bad_origin"}} =
               get_with(dash, "Host: 127.0.0.1:#{port}\r\nOrigin: null\r\n")

      for ok <- [
            "Host: 127.0.0.1:#{port}\r\n",
            "Host: 127.0.0.1\r\n",
            "Host: LOCALHOST:#{port}\r\n",
            "Host: dash.example:#{port}\r\n",
            "Host: localhost:#{port}\r\nOrigin: http://localhost:#{port}\r\n"
          ] do
        assert {200, %{"node" => _}} = get_with(dash, ok), ok
      end
    end

    test "a POST from a foreign Host is refused before the token or the body count" do
      dash = start([])
      sock = connect(dash)

      :ok =
        :gen_tcp.send(sock, [
          "POST /api/agents HTTP/1.1\r\nHost: evil.example\r\nAuthorization: Bearer #{@token}\r\n",
          "Transfer-Encoding: chunked\r\n\r\n",
          chunk("{}")
        ])

      assert {403, _, %{"error" => "bad_host"}} = answer(sock)
      assert closed?(sock)
    end
  end

  describe "slow and idle connections" do
    test "a connection that sends no request line is closed after idle_timeout (408)" do
      dash = start(idle_timeout: 200)
      sock = connect(dash)
      :ok = :gen_tcp.send(sock, "GET /api/info HT")
      assert {408, _, %{"error" => "request_timeout"}} = answer(sock)
      assert closed?(sock)
    end

    test "a kept-alive connection is closed after idle_timeout without a word" do
      dash = start(idle_timeout: 200)
      sock = connect(dash)
      :ok = :gen_tcp.send(sock, "GET /api/info HTTP/1.1\r\nHost: #{host(dash)}\r\n\r\n")
      assert {200, _, _} = answer(sock)
      assert closed?(sock)
    end

    test "headers dripped slowly get 408 once request_timeout is over" do
      dash = start(idle_timeout: 60_000, request_timeout: 300)
      sock = connect(dash)
      :ok = :gen_tcp.send(sock, "GET /api/info HTTP/1.1\r\nHost: #{host(dash)}\r\n")
      drip = spawn_link(fn -> drip(sock, 0) end)
      assert {408, _, %{"error" => "request_timeout"}} = answer(sock)
      Process.unlink(drip)
      Process.exit(drip, :kill)
    end

    test "a body sent slowly gets 408 once request_timeout is over" do
      dash = start(idle_timeout: 60_000, request_timeout: 300)
      sock = connect(dash)

      :ok =
        :gen_tcp.send(
          sock,
          "POST /api/agents HTTP/1.1\r\nHost: #{host(dash)}\r\nX-Tartarus-Token: #{@token}\r\nContent-Length: 1000\r\n\r\n{"
        )

      assert {408, _, %{"error" => "request_timeout"}} = answer(sock)
      assert closed?(sock)
    end
  end

  # A header line every 50 ms, until the socket refuses (at most 10 s).
  defp drip(sock, n) when n < 200 do
    Process.sleep(50)
    if :gen_tcp.send(sock, "X-Slow-#{n}: 1\r\n") == :ok, do: drip(sock, n + 1)
  end

  defp drip(_sock, _n), do: :ok

  describe "connections at once" do
    test "beyond max_per_client connections from one address, a connection gets 503 and the close" do
      dash = start(max_per_client: 2)
      held = for _ <- 1..2, do: connect(dash)
      await_connections(dash, 2)

      extra = connect(dash)
      assert {503, _, %{"error" => "too_many_connections", "message" => m}} = answer(extra)
      assert m =~ "at most 2 connections at once from one address (127.0.0.1)"
      assert closed?(extra)

      # Held ones are served; once one goes, another client connection is served again.
      [a, b] = held
      :ok = :gen_tcp.send(a, "GET /api/info HTTP/1.1\r\nHost: #{host(dash)}\r\n\r\n")
      assert {200, _, _} = answer(a)
      :gen_tcp.close(b)
      await_connections(dash, 1)
      sock = connect(dash)
      :ok = :gen_tcp.send(sock, "GET /api/info HTTP/1.1\r\nHost: #{host(dash)}\r\n\r\n")
      assert {200, _, _} = answer(sock)
    end

    test "beyond max_clients connections in all, a connection gets 503" do
      dash = start(max_clients: 3, max_per_client: 10)
      _held = for _ <- 1..3, do: connect(dash)
      await_connections(dash, 3)
      extra = connect(dash)
      assert {503, _, %{"message" => m}} = answer(extra)
      assert m =~ "at most 3 connections at once"
    end
  end

  describe "bad input, round four (issue 44)" do
    test "a malformed or non-UTF-8 percent-encoding gets 400; a good one is decoded" do
      dash = start([])

      for target <- [
            "/%ff%fe",
            "/api/agents/%zz",
            "/api/%",
            "/api/info?x=%e2%28",
            "/api/info?a%=1"
          ] do
        sock = connect(dash)
        :ok = :gen_tcp.send(sock, "GET #{target} HTTP/1.1\r\nHost: #{host(dash)}\r\n\r\n")
        assert {400, _, %{"error" => "bad_request", "message" => m}} = answer(sock), target
        assert m =~ "percent-encoding"
      end

      sock = connect(dash)

      :ok =
        :gen_tcp.send(sock, "GET /api/%69nfo?x=%C3%A9 HTTP/1.1\r\nHost: #{host(dash)}\r\n\r\n")

      assert {200, _, %{"node" => _}} = answer(sock)
    end

    test "a Content-Length that is not digits alone gets 400 before the body is read" do
      dash = start([])

      for length <- ["+5", "-0", "5 5", "0x5", "5e0", "5,5"] do
        sock = connect(dash)

        :ok =
          :gen_tcp.send(
            sock,
            "POST /api/agents HTTP/1.1\r\nHost: #{host(dash)}\r\nX-Tartarus-Token: #{@token}\r\nContent-Length: #{length}\r\n\r\n{}xyz"
          )

        assert {400, _, %{"error" => "bad_request", "message" => m}} = answer(sock), length
        assert m =~ "Content-Length", length
      end
    end

    test "chunked trailers are read and ignored, long lines and lines in pieces too", c do
      dash = start([])
      sock = connect(dash)
      json = ~s({"host":"#{c.host}","module":"Tartarus.Examples.Echo"})

      # Each part in a segment of its own; a trailer line longer than the socket's buffer.
      for part <- [
            "POST /api/agents HTTP/1.1\r\nHost: #{host(dash)}\r\nX-Tartarus-Token: #{@token}\r\n",
            "Transfer-Encoding: chunked\r\nTrailer: X-Digest, X-Note\r\n\r\n",
            chunk(json),
            "0\r\n",
            "X-Digest: #{String.duplicate("a", 3_000)}",
            "\r\nX-Note: ",
            "yes\r\n",
            "\r\n"
          ] do
        :ok = :gen_tcp.send(sock, part)
        Process.sleep(20)
      end

      assert {201, h, %{"ok" => true, "host" => host}} = answer(sock)
      assert host == c.host and h["connection"] == nil
      :ok = :gen_tcp.send(sock, "GET /api/info HTTP/1.1\r\nHost: #{host(dash)}\r\n\r\n")
      assert {200, _, %{"node" => _}} = answer(sock)
    end
  end

  describe "connection slots shared between client addresses (issue 44)" do
    test "when other addresses' slow connections hold every slot, a new address is still served" do
      dash = start(max_clients: 6, max_per_client: 3)

      held =
        for a <- [2, 3], _ <- 1..3 do
          sock = connect(dash, {127, 0, 0, a})
          :ok = :gen_tcp.send(sock, "GET /api/info HT")
          sock
        end

      await_connections(dash, 6)

      sock = connect(dash, {127, 0, 0, 4})
      :ok = :gen_tcp.send(sock, "GET /api/info HTTP/1.1\r\nHost: #{host(dash)}\r\n\r\n")
      assert {200, _, %{"node" => _}} = answer(sock)

      # One slow connection of an address holding the most gave its slot up.
      %{total: 6, per_client: per} = connections(dash)
      assert per[{127, 0, 0, 4}] == 1
      assert Enum.sort(Map.values(per)) == [1, 2, 3]
      assert Enum.count(held, &(:gen_tcp.recv(&1, 0, 200) == {:error, :closed})) == 1

      # An address holding its share does not take another's slot: 503.
      extra = connect(dash, {127, 0, 0, 2})
      assert {503, _, %{"error" => "too_many_connections"}} = answer(extra)
      assert %{total: 6} = connections(dash)
    end
  end

  describe "what a read may cost the overlay (issue 44)" do
    setup do
      {:module, _} = Code.ensure_loaded(Tartarus.Locator.Walk)
      search = {Tartarus.Locator.Walk, :search, 3}
      :erlang.trace_pattern(search, true, [:call_count])
      on_exit(fn -> :erlang.trace_pattern(search, false, [:call_count]) end)
      %{searches: fn -> elem(:erlang.trace_info(search, :call_count), 1) end}
    end

    defp get_agent(sock, dash, id) do
      :ok = :gen_tcp.send(sock, "GET /api/agents/#{id} HTTP/1.1\r\nHost: #{host(dash)}\r\n\r\n")
      answer(sock)
    end

    test "an unknown id is searched for once, then answered from the miss for a while", c do
      # (search_miss_ms: 5 s by default.)
      dash = start([])
      sock = connect(dash)

      for _ <- 1..20 do
        assert {404, _, %{"error" => "unknown_agent"}} = get_agent(sock, dash, "0123456789abcdef")
      end

      assert c.searches.() == 1
    end

    test "an address starts at most search_rate searches a second (429 beyond); others are not held back",
         c do
      # (search_rate: 2 by default.)
      dash = start([])
      sock = connect(dash)
      second = fn -> div(Tartarus.Clock.machine_time(:millisecond), 1_000) end
      first = second.()

      statuses =
        for _ <- 1..20 do
          id = Base.encode16(:crypto.strong_rand_bytes(8), case: :lower)
          {status, _, %{"error" => code}} = get_agent(sock, dash, id)
          {status, code}
        end

      seconds = second.() - first + 1
      assert {429, "too_many_searches"} in statuses
      assert Enum.all?(statuses, &(&1 in [{404, "unknown_agent"}, {429, "too_many_searches"}]))
      assert c.searches.() <= 2 * seconds
      assert Enum.count(statuses, &(&1 == {404, "unknown_agent"})) == c.searches.()

      other = connect(dash, {127, 0, 0, 2})
      assert {404, _, %{"error" => "unknown_agent"}} = get_agent(other, dash, "00000000000000aa")
    end
  end

  defp connections(dash), do: TartarusDashboard.Http.connections(:sys.get_state(dash).http)

  defp await_connections(dash, n) do
    eventually(fn -> connections(dash).total == n end)
  end
end
