defmodule TartarusTools.Browser do
  @moduledoc """
  A real headless Chromium driven over the DevTools protocol (a small WebSocket client on
  `:gen_tcp`, no dependency): the dashboard's browser tests and its benchmark open the page
  with it, read what the browser rendered, click, and take screenshots.

      {:ok, b} = TartarusTools.Browser.start()
      :ok = TartarusTools.Browser.open(b, "http://127.0.0.1:4040/")
      {:ok, 2} = TartarusTools.Browser.eval(b, "document.querySelectorAll('[data-host]').length")
      :ok = TartarusTools.Browser.screenshot(b, "page.png")
      :ok = TartarusTools.Browser.stop(b)

  Chromium runs in its own process group (started with `setsid`) with a throw-away
  profile directory; `stop/1` kills the whole group and removes the directory, and so does
  the exit of the process that started it. If the whole BEAM goes without either (a script
  that ends, a node killed), the small shell that started Chromium sees its input close
  and kills it: no browser outlives its node. `executable/0` finds Debian's `chromium`.
  """

  use GenServer

  alias Tartarus.Clock
  alias Tartarus.MachineClock
  require Tartarus.MachineClock

  @typedoc "A running browser."
  @type t :: pid()

  @doc "The Chromium executable on the PATH (`chromium`, `chromium-browser`), or nil."
  @spec executable() :: String.t() | nil
  def executable do
    Enum.find_value(["chromium", "chromium-browser", "google-chrome"], &System.find_executable/1)
  end

  @doc """
  Starts headless Chromium with one blank page (options: `:width`, `:height`,
  `:timeout` in ms to wait for it, default 90 s: a loaded machine starts it slowly). Returns `{:ok, browser}` or `{:error, reason}`.
  """
  @spec start(keyword()) :: {:ok, t()} | {:error, term()}
  def start(opts \\ []), do: GenServer.start(__MODULE__, {self(), opts})

  @doc "Kills Chromium (its whole process group) and removes its profile directory."
  @spec stop(t()) :: :ok
  def stop(b) do
    GenServer.stop(b)
  catch
    :exit, _ -> :ok
  end

  @doc "Opens `url` in the page and waits for it to load."
  @spec open(t(), String.t()) :: :ok | {:error, term()}
  def open(b, url) do
    with {:ok, _} <- command(b, "Page.enable", %{}),
         {:ok, _} <- command(b, "Page.navigate", %{url: url}) do
      wait(b, "document.readyState === 'complete'", 10_000)
    end
  end

  @doc """
  Evaluates a JavaScript expression in the page (promises are awaited) and returns its
  value as JSON-decoded data: `{:ok, value}` or `{:error, reason}`.
  """
  @spec eval(t(), String.t()) :: {:ok, term()} | {:error, term()}
  def eval(b, expression) do
    case command(b, "Runtime.evaluate", %{
           expression: expression,
           returnByValue: true,
           awaitPromise: true
         }) do
      {:ok, %{"exceptionDetails" => d}} -> {:error, {:js, d["exception"]["description"] || d["text"]}}
      {:ok, %{"result" => r}} -> {:ok, r["value"]}
      error -> error
    end
  end

  @doc """
  Polls `expression` every 50 ms until it is truthy; `:ok`, or `{:error, :timeout}` after
  `timeout` ms.
  """
  @spec wait(t(), String.t(), non_neg_integer()) :: :ok | {:error, :timeout}
  def wait(b, expression, timeout \\ 5_000) do
    deadline = Clock.machine_time(:millisecond) + timeout
    poll(b, expression, deadline)
  end

  defp poll(b, expression, deadline) do
    case eval(b, "!!(#{expression})") do
      {:ok, true} ->
        :ok

      _ ->
        if Clock.machine_time(:millisecond) > deadline do
          {:error, :timeout}
        else
          Clock.machine_sleep(50)
          poll(b, expression, deadline)
        end
    end
  end

  @doc "Writes a PNG screenshot of the page to `path`."
  @spec screenshot(t(), Path.t()) :: :ok | {:error, term()}
  def screenshot(b, path) do
    with {:ok, %{"data" => data}} <- command(b, "Page.captureScreenshot", %{format: "png"}) do
      File.mkdir_p!(Path.dirname(path))
      File.write(path, Base.decode64!(data))
    end
  end

  @doc "Sends one DevTools protocol command; `{:ok, result}` or `{:error, reason}`."
  @spec command(t(), String.t(), map()) :: {:ok, map()} | {:error, term()}
  def command(b, method, params), do: GenServer.call(b, {:command, method, params}, 30_000)

  # -- the server: owns Chromium's port and the WebSocket -------------------------------

  # Starts `setsid -w chromium ...` ($2...) and waits for it (its end ends the port). A
  # watcher reads the port's input: when it closes (the port closed, or the BEAM is gone
  # without stopping the browser), it kills Chromium's process group, setsid, and anything
  # still naming the profile directory ($1).
  @guard """
  dir=$1; shift
  exec 3<&0
  "$@" </dev/null &
  p=$!
  ( cat <&3 >/dev/null
    for c in $(pgrep -P "$p"); do kill -KILL -- "-$c" 2>/dev/null; done
    kill -KILL "$p" 2>/dev/null
    pkill -KILL -f -- "$dir" 2>/dev/null ) &
  exec 3<&-
  wait "$p"
  """

  @impl true
  def init({owner, opts}) do
    Process.flag(:trap_exit, true)
    Process.monitor(owner)

    with exe when is_binary(exe) <- executable() || {:error, :no_chromium},
         setsid when is_binary(setsid) <- System.find_executable("setsid") || {:error, :no_setsid},
         sh when is_binary(sh) <- System.find_executable("sh") || {:error, :no_sh} do
      dir = Path.join(System.tmp_dir!(), "tartarus-chromium-#{System.unique_integer([:positive])}")
      File.mkdir_p!(dir)

      args = [
        exe,
        "--headless=new",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--no-first-run",
        "--remote-debugging-port=0",
        "--remote-debugging-address=127.0.0.1",
        "--user-data-dir=#{dir}",
        "--window-size=#{opts[:width] || 1400},#{opts[:height] || 1000}",
        "about:blank"
      ]

      port =
        Port.open({:spawn_executable, sh}, [
          :binary,
          :exit_status,
          :stderr_to_stdout,
          args: ["-c", @guard, "tartarus-chromium", dir, setsid, "-w" | args]
        ])

      {:os_pid, pid} = Port.info(port, :os_pid)
      s = %{port: port, pid: pid, dir: dir, sock: nil, buf: "", next: 1}

      case devtools_url(port, "", Clock.machine_time(:millisecond) + (opts[:timeout] || 90_000)) do
        {:ok, url} ->
          case page_socket(url) do
            {:ok, sock, rest} ->
              {:ok, %{s | sock: sock, buf: rest}}

            {:error, reason} ->
              cleanup(s)
              {:stop, reason}
          end

        {:error, reason} ->
          cleanup(s)
          {:stop, reason}
      end
    else
      {:error, reason} -> {:stop, reason}
    end
  end

  defp devtools_url(port, acc, deadline) do
    left = deadline - Clock.machine_time(:millisecond)

    MachineClock.receive do
      {^port, {:data, data}} ->
        acc = acc <> data

        case Regex.run(~r{DevTools listening on (ws://[^\s]+)}, acc) do
          [_, url] -> {:ok, url}
          nil -> devtools_url(port, acc, deadline)
        end

      {^port, {:exit_status, n}} ->
        {:error, {:chromium_exited, n, String.slice(acc, -500, 500)}}
    after
      max(left, 0) -> {:error, :chromium_did_not_start}
    end
  end

  # The browser's URL names its port; the blank page's socket is in /json/list.
  defp page_socket(browser_url) do
    %URI{host: host, port: port} = URI.parse(browser_url)
    {:ok, _} = Application.ensure_all_started(:inets)
    list_url = ~c"http://#{host}:#{port}/json/list"

    with {:ok, {{_, 200, _}, _, body}} <- :httpc.request(:get, {list_url, []}, [timeout: 5_000], []),
         {:ok, targets} <- Tartarus.JSON.decode(IO.iodata_to_binary(body)),
         %{"webSocketDebuggerUrl" => ws} <-
           Enum.find(targets, &(&1["type"] == "page")) || {:error, :no_page} do
      ws_connect(ws)
    else
      {:error, _} = e -> e
      other -> {:error, other}
    end
  end

  defp ws_connect(url) do
    %URI{host: host, port: port, path: path} = URI.parse(url)
    key = Base.encode64(:crypto.strong_rand_bytes(16))

    with {:ok, sock} <-
           :gen_tcp.connect(String.to_charlist(host), port, [:binary, active: false, packet: :raw], 5_000),
         :ok <-
           :gen_tcp.send(
             sock,
             "GET #{path} HTTP/1.1\r\nHost: #{host}:#{port}\r\nUpgrade: websocket\r\n" <>
               "Connection: Upgrade\r\nSec-WebSocket-Key: #{key}\r\nSec-WebSocket-Version: 13\r\n\r\n"
           ),
         {:ok, head, rest} <- read_head(sock, "") do
      if String.starts_with?(head, "HTTP/1.1 101"),
        do: {:ok, sock, rest},
        else: {:error, {:websocket_refused, head}}
    end
  end

  defp read_head(sock, acc) do
    case :binary.split(acc, "\r\n\r\n") do
      [head, rest] ->
        {:ok, head, rest}

      [_] ->
        case :gen_tcp.recv(sock, 0, 5_000) do
          {:ok, data} -> read_head(sock, acc <> data)
          error -> error
        end
    end
  end

  @impl true
  def handle_call({:command, method, params}, _from, s) do
    id = s.next
    frame = Tartarus.JSON.encode!(%{id: id, method: method, params: params})
    s = %{s | next: id + 1}

    with :ok <- :gen_tcp.send(s.sock, encode_frame(frame)),
         {:ok, reply, buf} <- await(s.sock, s.buf, id) do
      s = %{s | buf: buf}

      case reply do
        %{"error" => e} -> {:reply, {:error, {:devtools, e["message"]}}, s}
        %{"result" => r} -> {:reply, {:ok, r}, s}
      end
    else
      {:error, reason} -> {:reply, {:error, reason}, s}
    end
  end

  defp await(sock, buf, id) do
    case read_message(sock, buf, "") do
      {:ok, text, buf} ->
        case Tartarus.JSON.decode(text) do
          {:ok, %{"id" => ^id} = m} -> {:ok, m, buf}
          _ -> await(sock, buf, id)
        end

      error ->
        error
    end
  end

  # One whole message (fragments joined); control frames are answered or skipped.
  defp read_message(sock, buf, acc) do
    with {:ok, fin, op, payload, buf} <- read_frame(sock, buf) do
      case op do
        9 ->
          :gen_tcp.send(sock, encode_frame(payload, 10))
          read_message(sock, buf, acc)

        8 ->
          {:error, :closed}

        op when op in [0, 1, 2] ->
          if fin, do: {:ok, acc <> payload, buf}, else: read_message(sock, buf, acc <> payload)

        _ ->
          read_message(sock, buf, acc)
      end
    end
  end

  defp read_frame(sock, buf) do
    case buf do
      <<fin::1, _::3, op::4, 0::1, 127::7, len::64, payload::binary-size(len), rest::binary>> ->
        {:ok, fin == 1, op, payload, rest}

      <<fin::1, _::3, op::4, 0::1, 126::7, len::16, payload::binary-size(len), rest::binary>> ->
        {:ok, fin == 1, op, payload, rest}

      <<fin::1, _::3, op::4, 0::1, len::7, payload::binary-size(len), rest::binary>> when len < 126 ->
        {:ok, fin == 1, op, payload, rest}

      _ ->
        case :gen_tcp.recv(sock, 0, 20_000) do
          {:ok, data} -> read_frame(sock, buf <> data)
          error -> error
        end
    end
  end

  defp encode_frame(payload, op \\ 1) do
    mask = :crypto.strong_rand_bytes(4)
    len = byte_size(payload)

    size =
      cond do
        len < 126 -> <<1::1, len::7>>
        len < 65_536 -> <<1::1, 126::7, len::16>>
        true -> <<1::1, 127::7, len::64>>
      end

    [<<1::1, 0::3, op::4>>, size, mask, mask(payload, mask)]
  end

  defp mask(payload, <<m::32>>) do
    n = byte_size(payload)
    pad = rem(4 - rem(n, 4), 4)
    words = for <<w::32 <- payload <> :binary.copy(<<0>>, pad)>>, into: <<>>, do: <<Bitwise.bxor(w, m)::32>>
    binary_part(words, 0, n)
  end

  @impl true
  def handle_info({port, {:data, _}}, %{port: port} = s), do: {:noreply, s}
  def handle_info({port, {:exit_status, _}}, %{port: port} = s), do: {:stop, :normal, s}
  def handle_info({:DOWN, _, :process, _, _}, s), do: {:stop, :normal, s}
  def handle_info(_, s), do: {:noreply, s}

  @impl true
  def terminate(_reason, s), do: cleanup(s)

  defp cleanup(s) do
    if s[:sock], do: :gen_tcp.close(s.sock)
    # `setsid -w` made Chromium (its child) the leader of a new process group: end the
    # group, then any process still naming our profile directory (the crash handler
    # detaches into a group of its own).
    # (s.pid is the guarding shell; setsid is its child, Chromium setsid's.)
    setsids = children(s.pid)
    groups = for p <- setsids, pid <- children(p), do: "-#{pid}"
    pids = Enum.map([s.pid | setsids], &to_string/1)
    _ = System.cmd("kill", ["-KILL", "--" | groups] ++ pids, stderr_to_stdout: true)
    _ = System.cmd("kill", ["-KILL" | Enum.map(naming(s.dir), &to_string/1)], stderr_to_stdout: true)
    File.rm_rf(s.dir)
    :ok
  end

  defp children(ppid) do
    for pid <- procs(), stat = read("/proc/#{pid}/stat"), ppid_of(stat) == ppid, do: pid
  end

  defp naming(dir) do
    for pid <- procs(), cmd = read("/proc/#{pid}/cmdline"), cmd != nil and String.contains?(cmd, dir), do: pid
  end

  defp procs do
    case File.ls("/proc") do
      {:ok, names} -> for n <- names, {pid, ""} <- [Integer.parse(n)], do: pid
      _ -> []
    end
  end

  defp read(path) do
    case File.read(path) do
      {:ok, text} -> text
      _ -> nil
    end
  end

  # /proc/PID/stat: "pid (comm) state ppid ..."; comm may hold spaces, so split after ")".
  defp ppid_of(nil), do: nil

  defp ppid_of(stat) do
    case stat |> String.split(")") |> List.last() |> String.split(" ", trim: true) do
      [_state, ppid | _] -> String.to_integer(ppid)
      _ -> nil
    end
  end
end
