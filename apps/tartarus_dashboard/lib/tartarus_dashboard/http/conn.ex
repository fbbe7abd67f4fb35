defmodule TartarusDashboard.Http.Conn do
  @moduledoc false
  # One HTTP/1.1 connection of the dashboard (started by TartarusDashboard.Http), in
  # its own process. Per request, in this order:
  #
  #   1. the request line, within :idle_timeout of the connection's start or of the last
  #      answer (else the connection is closed; 408 if nothing was answered on it yet);
  #   2. the headers, at most 100 lines (431), and everything up to the body's last byte
  #      within :request_timeout of the request line (408). A request line or header
  #      line longer than @line_max bytes closes the connection without an answer
  #      (OTP's packet parsing, which enforces the bound, closes the socket);
  #   3. the Host (and the Origin, if sent) must name this dashboard (403; DNS rebinding);
  #   4. the body's framing: Content-Length or chunked, not both (400), no other coding
  #      (501);
  #   5. what needs no body: an action needs the token (401, 403);
  #   6. a declared length above :max_body is refused (413);
  #   7. the body, read with the limit whatever the framing (413 as soon as a chunk goes
  #      over), then TartarusDashboard.Api answers.
  #
  # An answer before the body was read is sent with "Connection: close"; the connection
  # then shuts its side, discards what the client still sends (at most @linger_bytes or
  # @linger_ms, so that the client reads the answer rather than a reset) and closes.
  # Nothing of a refused body is kept: memory per connection is bounded by :max_body.

  alias TartarusDashboard.{Api, Feed}
  alias Tartarus.Clock
  alias Tartarus.MachineClock
  require Tartarus.MachineClock
  alias Tartarus.JSON

  # The longest request, header or chunk line (the listening socket's packet_size).
  @line_max 8_192

  @doc false
  def line_max, do: @line_max

  @max_headers 100
  @ping_ms 15_000
  @linger_ms 2_000
  @linger_bytes 1_048_576

  @doc false
  # The process's body: waits for its socket from the acceptor, then serves it.
  def start(conf) do
    MachineClock.receive do
      {:go, sock} -> serve(sock, conf)
    after
      5_000 -> :ok
    end
  end

  defp serve(sock, conf) do
    with {:ok, {ip, _}} <- :inet.sockname(sock),
         {:ok, {peer, _}} <- :inet.peername(sock) do
      names =
        MapSet.new([
          "localhost",
          "127.0.0.1",
          "[::1]",
          address(ip),
          address(conf.bind) | conf.hosts
        ])

      next(sock, Map.merge(conf, %{names: names, answered: 0, peer: peer}))
    else
      {:error, _} -> :gen_tcp.close(sock)
    end
  end

  defp address({_, _, _, _} = ip), do: to_string(:inet.ntoa(ip))
  defp address(ip), do: "[" <> String.downcase(to_string(:inet.ntoa(ip))) <> "]"

  # -- one request ------------------------------------------------------------------------

  defp next(sock, c) do
    case :gen_tcp.recv(sock, 0, c.idle_timeout) do
      {:ok, {:http_request, method, target, version}} ->
        deadline = now() + c.request_timeout

        case request(sock, c, method, target, version, deadline) do
          :keep_alive -> next(sock, %{c | answered: c.answered + 1})
          :close -> :gen_tcp.close(sock)
        end

      {:ok, _not_a_request_line} ->
        refuse(sock, 400, "bad_request", "the request line is not HTTP/1.1", :unread)

      {:error, :timeout} when c.answered == 0 ->
        refuse(
          sock,
          408,
          "request_timeout",
          "no request line within #{c.idle_timeout} ms",
          :unread
        )

      {:error, _timeout_closed_or_line_too_long} ->
        :gen_tcp.close(sock)
    end
  end

  defp request(sock, c, method, target, version, deadline) do
    with {:ok, headers} <- headers(sock, deadline, [], 0),
         {:ok, req} <- build(method, target, version, headers) do
      # From here on a refusal may leave a body unread (the close then lingers).
      case framing(req.headers) do
        {:ok, framing} ->
          case check_host(req, target, c) do
            :ok -> answer(sock, c, req, framing, deadline)
            {:error, status, code, message} -> refuse(sock, status, code, message, framing)
          end

        {:error, status, code, message} ->
          refuse(sock, status, code, message, :unread)
      end
    else
      {:error, status, code, message} -> refuse(sock, status, code, message, :unread)
      :closed -> :close
    end
  end

  defp answer(sock, c, req, framing, deadline) do
    with :ok <- admit(req, c),
         :ok <- declared_size(framing, c),
         :ok <- continue(sock, req, framing),
         {:ok, body} <- read_body(sock, framing, c.max_body, deadline) do
      respond(sock, c, Map.merge(req, %{body: body, peer: c.peer}))
    else
      {:answer, {status, type, body}} -> send_answer(sock, req, status, type, body, framing)
      {:error, status, code, message} -> refuse(sock, status, code, message, framing)
      :closed -> :close
    end
  end

  defp headers(sock, deadline, acc, n) do
    case :gen_tcp.recv(sock, 0, left(deadline)) do
      {:ok, {:http_header, _, _, name, value}} when n < @max_headers ->
        headers(sock, deadline, [{String.downcase(name), value} | acc], n + 1)

      {:ok, {:http_header, _, _, _, _}} ->
        {:error, 431, "too_many_headers", "a request has at most #{@max_headers} header lines"}

      {:ok, :http_eoh} ->
        {:ok, Enum.reverse(acc)}

      {:ok, _malformed} ->
        {:error, 400, "bad_request", "a header line is malformed"}

      {:error, :timeout} ->
        {:error, 408, "request_timeout", "the request's headers did not arrive in time"}

      {:error, _closed} ->
        :closed
    end
  end

  defp build(method, target, version, headers) do
    dups =
      for name <- ~w(host content-length transfer-encoding), count(headers, name) > 1, do: name

    cond do
      version not in [{1, 0}, {1, 1}] ->
        {:error, 505, "http_version_not_supported", "only HTTP/1.0 and HTTP/1.1 are served"}

      dups != [] ->
        {:error, 400, "bad_request", "the request has more than one #{hd(dups)} header"}

      true ->
        case path_of(target) do
          {:ok, {path, query}} ->
            {:ok,
             %{
               method: if(is_atom(method), do: Atom.to_string(method), else: method),
               path: path,
               query: query,
               headers: Map.new(headers),
               body: "",
               version: version
             }}

          {:error, :encoding} ->
            {:error, 400, "bad_request",
             "the request target's percent-encoding is malformed or does not decode to UTF-8"}

          :error ->
            {:error, 400, "bad_request", "the request target is not a path"}
        end
    end
  end

  defp count(headers, name), do: Enum.count(headers, fn {k, _} -> k == name end)

  defp path_of({:abs_path, uri}), do: split_uri(uri)
  defp path_of({:absoluteURI, _scheme, _host, _port, uri}), do: split_uri(uri)
  defp path_of(_asterisk_or_other), do: :error

  # The path and the query, percent-decoded: {:ok, {path, query}}, or {:error, :encoding}
  # when a "%" is not followed by two hexadecimal digits or what it decodes to is not UTF-8
  # (the API's answers quote paths and parameters as JSON strings).
  defp split_uri(uri) do
    {p, q} =
      case String.split(uri, "?", parts: 2) do
        [p, q] -> {p, q}
        [p] -> {p, ""}
      end

    if Regex.match?(~r/%(?![0-9A-Fa-f]{2})/, uri) do
      {:error, :encoding}
    else
      path = URI.decode(p)
      query = URI.decode_query(q)

      if String.valid?(path) and
           Enum.all?(query, fn {k, v} -> String.valid?(k) and String.valid?(v) end),
         do: {:ok, {path, query}},
         else: {:error, :encoding}
    end
  end

  # -- the Host and the Origin -------------------------------------------------------------

  # A page on another site whose name resolves to this machine (DNS rebinding) sends its
  # own name as Host and Origin: both must name this dashboard, by a loopback name, the
  # address the connection came to, or a name given in :hosts, with its port if one is
  # given. HTTP/1.1 requires a Host; an absolute request target's authority stands for it.
  defp check_host(req, target, c) do
    authority =
      case target do
        {:absoluteURI, _scheme, host, port, _} -> authority(host, port)
        _ -> req.headers["host"]
      end

    cond do
      authority == nil and req.version == {1, 1} ->
        {:error, 400, "bad_request", "an HTTP/1.1 request needs a Host header"}

      authority != nil and not ours?(authority, c) ->
        {:error, 403, "bad_host",
         "Host #{inspect(authority)} is not this dashboard: it answers to #{known(c)} on port #{c.port}"}

      not origin_ok?(req.headers["origin"], c) ->
        {:error, 403, "bad_origin",
         "Origin #{inspect(req.headers["origin"])} is not this dashboard: it answers to #{known(c)} on port #{c.port}"}

      true ->
        :ok
    end
  end

  defp authority(host, :undefined), do: to_string(host)
  defp authority(host, port), do: "#{host}:#{port}"

  defp known(c), do: c.names |> Enum.sort() |> Enum.join(", ")

  defp origin_ok?(nil, _c), do: true
  defp origin_ok?("http://" <> authority, c), do: ours?(authority, c)
  defp origin_ok?("https://" <> authority, c), do: ours?(authority, c)
  defp origin_ok?(_null_or_other, _c), do: false

  defp ours?(authority, c) do
    {name, port} =
      case Regex.run(~r/\A(\[[^\]]*\]|[^:\[\]]*)(?::(\d{1,5}))?\z/, String.trim(authority)) do
        [_, name] -> {name, nil}
        [_, name, port] -> {name, String.to_integer(port)}
        nil -> {nil, nil}
      end

    name != nil and MapSet.member?(c.names, String.downcase(name)) and port in [nil, c.port]
  end

  # -- the body ----------------------------------------------------------------------------

  defp framing(headers) do
    case {headers["transfer-encoding"], headers["content-length"]} do
      {nil, nil} ->
        {:ok, :none}

      {nil, length} ->
        # Digits only (RFC 9110's 1*DIGIT): no sign, no spaces inside, no list.
        digits = String.trim(length)

        cond do
          not Regex.match?(~r/\A[0-9]+\z/, digits) ->
            {:error, 400, "bad_request",
             "Content-Length #{inspect(length)} is not a length (digits only)"}

          String.to_integer(digits) == 0 ->
            {:ok, :none}

          true ->
            {:ok, {:length, String.to_integer(digits)}}
        end

      {coding, nil} ->
        if String.downcase(String.trim(coding)) == "chunked",
          do: {:ok, :chunked},
          else:
            {:error, 501, "not_implemented",
             "Transfer-Encoding #{inspect(coding)} is not served (only chunked)"}

      {_, _} ->
        {:error, 400, "bad_request",
         "a request cannot have both Transfer-Encoding and Content-Length"}
    end
  end

  defp admit(req, c) do
    case Api.admit(req, c.ctx) do
      :ok -> :ok
      answer -> {:answer, answer}
    end
  end

  defp declared_size({:length, n}, c) when n > c.max_body,
    do:
      {:error, 413, "body_too_large",
       "the request body has #{n} bytes; at most #{c.max_body} are accepted"}

  defp declared_size(_framing, _c), do: :ok

  # A client that waits for "100 Continue" before its body gets it once the checks passed.
  defp continue(sock, req, framing) do
    if framing != :none and String.downcase(req.headers["expect"] || "") == "100-continue",
      do: sent(:gen_tcp.send(sock, "HTTP/1.1 100 Continue\r\n\r\n")),
      else: :ok
  end

  defp read_body(_sock, :none, _max, _deadline), do: {:ok, ""}

  defp read_body(sock, {:length, n}, _max, deadline) do
    :ok = :inet.setopts(sock, packet: :raw)
    result = body_recv(sock, n, deadline)
    :ok = :inet.setopts(sock, packet: :http_bin)
    result
  end

  defp read_body(sock, :chunked, max, deadline) do
    result = chunks(sock, max, deadline, [], 0)
    :ok = :inet.setopts(sock, packet: :http_bin)
    result
  end

  defp body_recv(sock, n, deadline) do
    case :gen_tcp.recv(sock, n, left(deadline)) do
      {:ok, data} ->
        {:ok, data}

      {:error, :timeout} ->
        {:error, 408, "request_timeout", "the request's body did not arrive in time"}

      {:error, _} ->
        :closed
    end
  end

  # Chunked: a size line (hex, maybe ";extensions"), that many bytes and CRLF, ... until a
  # size of 0, then trailer lines up to an empty one (read and ignored, at most
  # @max_headers of them). Read line by line (packet: :line,
  # bounded by packet_size) and chunk by chunk (an exact length), never beyond what
  # the limit allows.
  defp chunks(sock, max, deadline, acc, total) do
    :ok = :inet.setopts(sock, packet: :line)

    with {:ok, line} <- line(sock, deadline),
         {:ok, size} <- chunk_size(line) do
      cond do
        size == 0 ->
          with :ok <- trailers(sock, deadline, 0),
               do: {:ok, IO.iodata_to_binary(Enum.reverse(acc))}

        total + size > max ->
          {:error, 413, "body_too_large",
           "the request body is over #{max} bytes; at most #{max} are accepted"}

        true ->
          :ok = :inet.setopts(sock, packet: :raw)

          case body_recv(sock, size + 2, deadline) do
            {:ok, <<data::binary-size(size), "\r\n">>} ->
              chunks(sock, max, deadline, [data | acc], total + size)

            {:ok, _} ->
              {:error, 400, "bad_request", "a chunk does not end with CRLF"}

            other ->
              other
          end
      end
    end
  end

  # A line longer than the socket's buffer (about 1,460 bytes) comes in pieces, each
  # without the line end: they are joined up to @line_max bytes.
  defp line(sock, deadline, acc \\ "") do
    case :gen_tcp.recv(sock, 0, left(deadline)) do
      {:ok, piece} ->
        line = acc <> piece

        cond do
          String.ends_with?(line, "\n") ->
            {:ok, line}

          byte_size(line) < @line_max ->
            line(sock, deadline, line)

          true ->
            {:error, 400, "bad_request",
             "a chunk or trailer line is longer than #{@line_max} bytes"}
        end

      {:error, :timeout} ->
        {:error, 408, "request_timeout", "the request's body did not arrive in time"}

      {:error, _} ->
        :closed
    end
  end

  defp chunk_size(line) do
    hex = line |> String.split(";", parts: 2) |> hd() |> String.trim()

    case Integer.parse(hex, 16) do
      {n, ""} when n >= 0 and byte_size(hex) <= 8 -> {:ok, n}
      _ -> {:error, 400, "bad_request", "a chunk size is not a hexadecimal number"}
    end
  end

  defp trailers(_sock, _deadline, n) when n >= @max_headers,
    do: {:error, 431, "too_many_headers", "a request has at most #{@max_headers} trailer lines"}

  defp trailers(sock, deadline, n) do
    with {:ok, line} <- line(sock, deadline) do
      if line in ["\r\n", "\n"], do: :ok, else: trailers(sock, deadline, n + 1)
    end
  end

  # -- answers -----------------------------------------------------------------------------

  defp respond(sock, c, req) do
    # While the API answers, this connection's slot is not given to another address.
    send(c.server, {:busy, self(), true})
    answer = call_api(req, c.ctx)
    send(c.server, {:busy, self(), false})

    case answer do
      :stream -> stream(sock, c.ctx)
      {status, type, body} -> send_answer(sock, req, status, type, body, :read)
    end
  end

  defp call_api(req, ctx) do
    Api.handle(req, ctx)
  rescue
    e ->
      {500, "application/json",
       JSON.encode!(%{
         error: "internal",
         message: "the dashboard failed on this request: " <> Exception.message(e)
       })}
  end

  # framing: :read (the body, if any, was read), or the request's framing when the answer
  # comes before its body (then the connection closes unless there was no body).
  defp send_answer(sock, req, status, type, body, framing) do
    keep? = framing in [:read, :none] and keep_alive?(req)
    body = if req.method == "HEAD", do: "", else: body

    case :gen_tcp.send(sock, head(status, type, IO.iodata_length(body), keep?) ++ [body]) do
      :ok when keep? -> :keep_alive
      :ok -> close(sock, framing)
      {:error, _} -> :close
    end
  end

  defp keep_alive?(%{version: {1, 1}, headers: h}),
    do: String.downcase(h["connection"] || "") != "close"

  defp keep_alive?(_http_1_0), do: false

  # An error answer, then the close (lingering if a body was left unread).
  defp refuse(sock, status, code, message, framing) do
    _ = :gen_tcp.send(sock, response(status, code, message))
    close(sock, framing)
  end

  @doc false
  # A whole JSON error answer that closes the connection.
  def response(status, code, message) do
    body = JSON.encode!(%{error: code, message: message})
    head(status, "application/json", byte_size(body), false) ++ [body]
  end

  defp head(status, type, length, keep?) do
    [
      "HTTP/1.1 #{status} #{reason(status)}\r\n",
      "Content-Type: #{type}\r\n",
      if(status in [204, 304], do: [], else: "Content-Length: #{length}\r\n"),
      "Cache-Control: no-store\r\nX-Content-Type-Options: nosniff\r\n",
      if(keep?, do: [], else: "Connection: close\r\n"),
      "\r\n"
    ]
  end

  defp close(sock, framing) when framing in [:none, :read] do
    :gen_tcp.close(sock)
    :close
  end

  defp close(sock, _body_unread) do
    _ = :gen_tcp.shutdown(sock, :write)
    _ = :inet.setopts(sock, packet: :raw)
    drain(sock, now() + @linger_ms, @linger_bytes)
    :gen_tcp.close(sock)
    :close
  end

  defp drain(sock, deadline, bytes) when bytes > 0 do
    case :gen_tcp.recv(sock, 0, left(deadline)) do
      {:ok, data} -> drain(sock, deadline, bytes - byte_size(data))
      {:error, _} -> :ok
    end
  end

  defp drain(_sock, _deadline, _bytes), do: :ok

  @reasons %{
    200 => "OK",
    201 => "Created",
    204 => "No Content",
    400 => "Bad Request",
    401 => "Unauthorized",
    403 => "Forbidden",
    404 => "Not Found",
    405 => "Method Not Allowed",
    408 => "Request Timeout",
    413 => "Content Too Large",
    414 => "URI Too Long",
    422 => "Unprocessable Content",
    429 => "Too Many Requests",
    431 => "Request Header Fields Too Large",
    500 => "Internal Server Error",
    501 => "Not Implemented",
    503 => "Service Unavailable",
    505 => "HTTP Version Not Supported"
  }

  defp reason(status), do: Map.get(@reasons, status, "Status")

  # -- the event stream --------------------------------------------------------------------

  # Server-sent events: the head by hand (no length, the connection closes at the end), then
  # batches from the feed as they come, a comment line every @ping_ms, until the client
  # goes (the socket is active once: its close arrives as a message; anything it sends
  # ends the stream) or stops taking what is sent (the send timeout closes the socket).
  defp stream(sock, ctx) do
    head =
      "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\n" <>
        "Connection: close\r\n\r\nretry: 2000\n\n"

    with :ok <- :gen_tcp.send(sock, head),
         :ok <- Feed.join(ctx.feed),
         :ok <- :inet.setopts(sock, packet: :raw, active: :once) do
      events(sock)
    end

    :gen_tcp.close(sock)
    :close
  end

  defp events(sock) do
    data =
      MachineClock.receive do
        {:sse, data} -> data
        {:tcp_closed, ^sock} -> :stop
        {:tcp_error, ^sock, _} -> :stop
        {:tcp, ^sock, _} -> :stop
      after
        @ping_ms -> ": ping\n\n"
      end

    if data != :stop and :gen_tcp.send(sock, data) == :ok, do: events(sock), else: :ok
  end

  # -- time --------------------------------------------------------------------------------

  defp now, do: Clock.machine_time(:millisecond)
  defp left(deadline), do: max(deadline - now(), 0)
  defp sent(:ok), do: :ok
  defp sent({:error, _}), do: :closed
end
