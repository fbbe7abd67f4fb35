defmodule TartarusDashboard.Http do
  @moduledoc false
  # The dashboard's HTTP/1.1 server, on :gen_tcp alone (OTP's :inets httpd reads a whole
  # body before its callback runs, and ignores its length limit for chunked bodies).
  #
  # This process owns the listening socket and admits connections: an acceptor process
  # (linked) accepts each one and asks here whether it may be served. At most
  # :max_per_client connections from one address, and at most :max_clients at once,
  # shared fairly between addresses: when all are taken, a connection from an address
  # that holds at least two fewer than the address holding the most takes a slot of that
  # address (one of its connections that is not in an API call is closed without an
  # answer). So many addresses' slow connections cannot keep another address out: each
  # address keeps at least its share (max_clients / addresses, rounded down). A
  # connection refused all the same gets a 503 and is closed at once, before anything of
  # its request is read. An admitted connection gets its own process (linked, counted
  # until it ends), TartarusDashboard.Http.Conn, which reads requests with limits
  # and time bounds, checks the Host, the Origin and the token before any body, and
  # answers through TartarusDashboard.Api; it says here when it enters and leaves an
  # API call ({:busy, pid, boolean}), so that a slot is never taken from a request being
  # answered.

  use GenServer

  alias TartarusDashboard.Http.Conn

  # A request line or a header line longer than this is refused (414, 431).
  @line_max Conn.line_max()

  # conf: %{bind, port, ctx, max_body, idle_timeout, request_timeout, max_clients,
  # max_per_client, hosts}. {:ok, pid} or {:error, message}.
  def start_link(conf) do
    case GenServer.start_link(__MODULE__, conf) do
      {:ok, pid} ->
        {:ok, pid}

      {:error, reason} ->
        # The failed server's exit reaches the caller (it traps exits): take it out of the
        # mailbox, the reason is the answer.
        receive do
          {:EXIT, _pid, ^reason} -> :ok
        after
          0 -> :ok
        end

        {:error, reason}
    end
  end

  def port(server), do: GenServer.call(server, :port)

  def stop(server) do
    GenServer.stop(server)
  catch
    :exit, _ -> :ok
  end

  # How many connections are being served, in all and per client address (for the tests).
  def connections(server), do: GenServer.call(server, :connections)

  @doc false
  def line_max, do: @line_max

  @impl true
  def init(conf) do
    Process.flag(:trap_exit, true)

    opts = [
      :binary,
      ip: conf.bind,
      active: false,
      packet: :http_bin,
      packet_size: @line_max,
      reuseaddr: true,
      backlog: 128,
      nodelay: true,
      send_timeout: conf.idle_timeout,
      send_timeout_close: true
    ]

    case :gen_tcp.listen(conf.port, opts) do
      {:ok, listen} ->
        {:ok, port} = :inet.port(listen)
        conf = Map.put(conf, :port, port)
        server = self()
        acceptor = spawn_link(fn -> accept(server, listen) end)
        conf = Map.put(conf, :server, self())

        {:ok,
         %{
           listen: listen,
           acceptor: acceptor,
           conf: conf,
           conns: %{},
           per_client: %{},
           busy: MapSet.new()
         }}

      {:error, :eaddrinuse} ->
        {:stop, "dashboard: port #{conf.port} is in use"}

      {:error, reason} ->
        {:stop,
         "dashboard: cannot listen on #{:inet.ntoa(conf.bind)}:#{conf.port}: #{:inet.format_error(reason)}"}
    end
  end

  @impl true
  def handle_call(:port, _from, s), do: {:reply, s.conf.port, s}

  def handle_call(:connections, _from, s),
    do: {:reply, %{total: map_size(s.conns), per_client: s.per_client}, s}

  def handle_call({:admit, ip}, _from, s) do
    here = Map.get(s.per_client, ip, 0)

    cond do
      here >= s.conf.max_per_client ->
        {:reply,
         {:full,
          "the dashboard serves at most #{s.conf.max_per_client} connections at once from one address (#{:inet.ntoa(ip)}); close one and try again"},
         s}

      map_size(s.conns) < s.conf.max_clients ->
        admitted(s, ip)

      victim = victim(s, here) ->
        Process.exit(victim, :kill)
        admitted(forget(s, victim), ip)

      true ->
        {:reply,
         {:full,
          "the dashboard serves at most #{s.conf.max_clients} connections at once, shared between client addresses; try again later"},
         s}
    end
  end

  defp admitted(s, ip) do
    pid = spawn_link(Conn, :start, [s.conf])
    per_client = Map.update(s.per_client, ip, 1, &(&1 + 1))
    {:reply, {:ok, pid}, %{s | conns: Map.put(s.conns, pid, ip), per_client: per_client}}
  end

  # A connection to close for one from an address holding `here`: of the address holding
  # the most (if that is more than here + 1), one that is not in an API call; else nil.
  defp victim(s, here) do
    {top, n} = Enum.max_by(s.per_client, fn {_ip, n} -> n end)

    if n > here + 1 do
      Enum.find_value(s.conns, fn {pid, ip} ->
        if ip == top and not MapSet.member?(s.busy, pid), do: pid
      end)
    end
  end

  defp forget(s, pid) do
    case Map.pop(s.conns, pid) do
      {nil, _} ->
        s

      {ip, conns} ->
        per_client =
          case Map.fetch!(s.per_client, ip) do
            1 -> Map.delete(s.per_client, ip)
            n -> Map.put(s.per_client, ip, n - 1)
          end

        %{s | conns: conns, per_client: per_client, busy: MapSet.delete(s.busy, pid)}
    end
  end

  @impl true
  def handle_info({:EXIT, pid, reason}, %{acceptor: pid} = s), do: {:stop, reason, s}

  def handle_info({:EXIT, pid, _reason}, s), do: {:noreply, forget(s, pid)}

  def handle_info({:busy, pid, true}, %{conns: conns} = s) when is_map_key(conns, pid),
    do: {:noreply, %{s | busy: MapSet.put(s.busy, pid)}}

  def handle_info({:busy, pid, false}, s), do: {:noreply, %{s | busy: MapSet.delete(s.busy, pid)}}

  def handle_info(_other, s), do: {:noreply, s}

  @impl true
  def terminate(_reason, s) do
    :gen_tcp.close(s.listen)
    Process.exit(s.acceptor, :kill)
    Enum.each(Map.keys(s.conns), &Process.exit(&1, :kill))
    :ok
  end

  # -- the acceptor ----------------------------------------------------------------------

  defp accept(server, listen) do
    case :gen_tcp.accept(listen) do
      {:ok, sock} ->
        admit(server, sock)
        accept(server, listen)

      {:error, :closed} ->
        :ok

      {:error, _out_of_descriptors_or_other} ->
        # Out of file descriptors (emfile, enfile) or a connection reset before it was
        # accepted: wait a little rather than spin.
        Tartarus.Clock.machine_sleep(50)
        accept(server, listen)
    end
  end

  defp admit(server, sock) do
    with {:ok, {ip, _port}} <- :inet.peername(sock),
         {:ok, pid} <- GenServer.call(server, {:admit, ip}, :infinity),
         :ok <- :gen_tcp.controlling_process(sock, pid) do
      send(pid, {:go, sock})
    else
      {:full, message} ->
        # The request is not read: the 503 goes out before anything, then the close.
        _ = :gen_tcp.send(sock, Conn.response(503, "too_many_connections", message))
        :gen_tcp.close(sock)

      _gone ->
        :gen_tcp.close(sock)
    end
  end
end
