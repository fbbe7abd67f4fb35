defmodule TartarusTools.Dashboard.Httpd do
  @moduledoc false
  # The glue to OTP's :inets httpd: starts a server whose only module is this one, turns
  # httpd's request record into a plain map for TartarusTools.Dashboard.Api and its answer
  # into a response; /api/stream is answered here, by this request's own process, which
  # then stays in a loop writing server-sent events until the client goes.

  require Record
  Record.defrecordp(:mod, Record.extract(:mod, from_lib: "inets/include/httpd.hrl"))

  alias TartarusTools.Dashboard.{Api, Feed}

  @ping_ms 15_000

  def start(bind, port, ctx) do
    root = Path.join(System.tmp_dir!(), "tartarus_dashboard")
    File.mkdir_p!(root)
    key = {__MODULE__, make_ref()}
    :persistent_term.put(key, ctx)

    config = [
      port: port,
      bind_address: bind,
      server_name: ~c"tartarus-dashboard",
      server_root: String.to_charlist(root),
      document_root: String.to_charlist(root),
      modules: [__MODULE__],
      max_content_length: 1_000_000,
      max_clients: 200,
      keep_alive: true,
      keep_alive_timeout: 60,
      tartarus_dashboard: key
    ]

    case :inets.start(:httpd, config) do
      {:ok, pid} ->
        {:port, real} = List.keyfind(:httpd.info(pid), :port, 0)
        {:ok, {pid, key}, real}

      {:error, reason} ->
        :persistent_term.erase(key)
        {:error, listen_error(reason, port)}
    end
  end

  # :inets buries a listen error in nested supervisor shutdowns; a port in use is said so.
  defp listen_error(reason, port) do
    if in_term?(reason, {:listen, :eaddrinuse}),
      do: "dashboard: port #{port} is in use",
      else: reason
  end

  defp in_term?(term, term), do: true
  defp in_term?(term, x) when is_tuple(term), do: in_term?(Tuple.to_list(term), x)
  defp in_term?(term, x) when is_list(term), do: Enum.any?(term, &in_term?(&1, x))
  defp in_term?(_term, _x), do: false

  def stop({pid, key}) do
    _ = :inets.stop(:httpd, pid)
    :persistent_term.erase(key)
    :ok
  catch
    _, _ -> :ok
  end

  # -- the httpd module callback -------------------------------------------------------

  @doc false
  def unquote(:do)(m) do
    key = :httpd_util.lookup(mod(m, :config_db), :tartarus_dashboard)
    ctx = :persistent_term.get(key)
    req = request(m)

    case Api.handle(req, ctx) do
      :stream -> stream(m, ctx)
      {status, type, body} -> respond(status, type, body)
    end
  rescue
    e ->
      body =
        TartarusTools.JSON.encode!(%{
          error: "internal",
          message: "the dashboard failed on this request: " <> Exception.message(e)
        })

      respond(500, "application/json", body)
  end

  defp request(m) do
    uri = to_string(mod(m, :request_uri))
    {path, query} = split_uri(uri)

    %{
      method: to_string(mod(m, :method)),
      path: path,
      query: query,
      headers:
        Map.new(mod(m, :parsed_header), fn {k, v} -> {String.downcase(to_string(k)), to_string(v)} end),
      body: body(mod(m, :entity_body))
    }
  end

  defp body(b) when is_list(b), do: IO.iodata_to_binary(b)
  defp body(b) when is_binary(b), do: b
  defp body(_), do: ""

  defp split_uri(uri) do
    case String.split(uri, "?", parts: 2) do
      [p, q] -> {URI.decode(p), URI.decode_query(q)}
      [p] -> {URI.decode(p), %{}}
    end
  rescue
    _ -> {uri, %{}}
  end

  defp respond(status, type, body) do
    body = IO.iodata_to_binary(body)

    head = [
      code: status,
      content_type: String.to_charlist(type),
      content_length: Integer.to_charlist(byte_size(body)),
      cache_control: ~c"no-store"
    ]

    {:proceed, [response: {:response, head, body}]}
  end

  # Server-sent events: the head by hand (no length, the connection closes at the end),
  # then batches from the feed as they come, a comment line every @ping_ms.
  defp stream(m, ctx) do
    type = mod(m, :socket_type)
    sock = mod(m, :socket)

    head =
      "HTTP/1.1 200 OK\r\nContent-Type: text/event-stream\r\nCache-Control: no-store\r\n" <>
        "Connection: close\r\n\r\nretry: 2000\n\n"

    :ok = Feed.join(ctx.feed)

    if :httpd_socket.deliver(type, sock, head) == :ok, do: loop(type, sock)
    {:proceed, [response: {:already_sent, 200, 0}]}
  end

  defp loop(type, sock) do
    data =
      receive do
        {:sse, data} -> data
      after
        @ping_ms -> ": ping\n\n"
      end

    if :httpd_socket.deliver(type, sock, data) == :ok, do: loop(type, sock), else: :ok
  end
end
