defmodule TartarusTools.Peer do
  @moduledoc """
  Real BEAM nodes on this machine, started with OTP's `:peer`, running Tartarus.

  Used by the multi-node tests, the benchmarks, the demo and the emulator's `:peer` mode.
  Each peer gets this node's code path (so it runs the same platform code), its cookie, and
  `-connect_all false`: it connects only to the nodes its hosts talk to, never a full mesh.
  Peers are linked to the process that starts them and die with it.

  Code that is compiled at run time on the origin (e.g. an agent typed in iex) is *not* on
  the peers' code path: it reaches them only by migration, which is the point of
  on-the-fly programming.

  ## Example

      {:ok, peer, node} = TartarusTools.Peer.start(:p1)
      {:ok, _} = :erpc.call(node, Tartarus, :start_host, [:h1])
      TartarusTools.Peer.stop(peer)
  """

  require Tartarus.MachineClock

  @typedoc "A peer's controlling process."
  @type peer :: pid()

  @doc """
  Makes this node distributed if it is not already (starting `epmd` if needed), with a
  short name `prefix_<unique>`.
  """
  @spec ensure_distributed(String.t()) :: :ok | {:error, term()}
  def ensure_distributed(prefix \\ "tartarus") do
    if Node.alive?() do
      :ok
    else
      :ok = start_epmd()
      name = :"#{prefix}_#{System.unique_integer([:positive])}_#{:os.getpid()}"
      start_node(name, 50)
    end
  end

  # `epmd -daemon` returns before the daemon it forks listens: a node started at once can
  # find no epmd (seen when this was the machine's first distributed VM). Tried again every
  # 100 ms, for up to 5 s.
  defp start_node(name, tries) do
    case Node.start(name, :shortnames) do
      {:ok, _} ->
        :ok

      {:error, {:already_started, _}} ->
        :ok

      {:error, _} when tries > 1 ->
        Tartarus.Clock.machine_sleep(100)
        start_node(name, tries - 1)

      {:error, reason} ->
        {:error, {:distribution_failed, reason}}
    end
  end

  @doc """
  Starts a peer node named `name` (an atom, unique on this machine) running Tartarus.

  Options:

    * `:args` - extra command-line arguments (strings) for the peer's `erl`;
    * `:apps` - applications to start on the peer (default `[:tartarus]`);
    * `:log_level` - the peer's Logger level (default `:warning`);
    * `:link` - link the peer to the caller (default `true`); unlinked peers can be killed
      (`kill/1`) without taking the caller down;
    * `:busy_wait` - let the peer's schedulers busy-wait (default `false`: nodes sharing
      a machine's cores would otherwise steal each other's CPU);
    * `:connection` - `:standard_io` to control the peer without distribution (default:
      distribution).
  """
  @spec start(atom(), keyword()) :: {:ok, peer(), node()} | {:error, term()}
  def start(name, opts \\ []) do
    # Over :standard_io the origin controls the peer without distribution (so the peers
    # may use a distribution the origin does not speak, e.g. TLS); they still need epmd.
    standard_io? = Keyword.get(opts, :connection) == :standard_io

    with :ok <- if(standard_io?, do: start_epmd(), else: ensure_distributed()) do
      cookie = if standard_io?, do: [], else: ["-setcookie", Atom.to_string(Node.get_cookie())]

      args =
        ["-connect_all", "false"] ++
          cookie ++ scheduler_args(opts) ++ code_path_args() ++ Keyword.get(opts, :args, [])

      spec = %{name: name, args: Enum.map(args, &String.to_charlist/1), wait_boot: 60_000}

      spec =
        case Keyword.get(opts, :connection) do
          nil -> spec
          conn -> Map.put(spec, :connection, conn)
        end

      start = if Keyword.get(opts, :link, true), do: &:peer.start_link/1, else: &:peer.start/1

      case start.(spec) do
        {:ok, pid, node} ->
          boot = [Keyword.get(opts, :apps, [:tartarus]), Keyword.get(opts, :log_level, :warning)]

          result =
            if Map.has_key?(spec, :connection),
              do: :peer.call(pid, __MODULE__, :boot, boot, 60_000),
              else: :erpc.call(node, __MODULE__, :boot, boot, 60_000)

          case result do
            :ok ->
              {:ok, pid, node}

            error ->
              stop(pid)
              {:error, {:boot_failed, error}}
          end

        {:error, reason} ->
          {:error, reason}
      end
    end
  end

  defp start_epmd do
    case System.find_executable("epmd") do
      nil ->
        {:error, :epmd_not_found}

      epmd ->
        _ = System.cmd(epmd, ["-daemon"], stderr_to_stdout: true)
        :ok
    end
  end

  @doc "Starts `n` peers named `prefix1..prefixN`; stops them all if one fails."
  @spec start_many(String.t(), pos_integer(), keyword()) ::
          {:ok, [{peer(), node()}]} | {:error, term()}
  def start_many(prefix, n, opts \\ []) do
    tag = System.unique_integer([:positive])

    Enum.reduce_while(1..n, {:ok, []}, fn i, {:ok, acc} ->
      case start(:"#{prefix}#{i}_#{tag}", opts) do
        {:ok, pid, node} ->
          {:cont, {:ok, [{pid, node} | acc]}}

        error ->
          Enum.each(acc, fn {pid, _} -> stop(pid) end)
          {:halt, error}
      end
    end)
    |> case do
      {:ok, list} -> {:ok, Enum.reverse(list)}
      error -> error
    end
  end

  @doc """
  Kills a peer's operating-system process with SIGKILL: no clean shutdown, no goodbye to
  other nodes, like a power cut. Returns once the node is gone.
  """
  @spec kill(node()) :: :ok
  def kill(node) do
    os_pid = :erpc.call(node, :os, :getpid, [], 5_000)
    Node.monitor(node, true)
    {_, 0} = System.cmd("kill", ["-9", List.to_string(os_pid)])

    Tartarus.MachineClock.receive do
      {:nodedown, ^node} -> :ok
    after
      10_000 -> :ok
    end
  catch
    _, _ -> :ok
  end

  @doc """
  Cuts distribution between nodes `a` and `b` (both reachable from here): each side gets a
  wrong cookie for the other and the connection is closed, so reconnection fails until
  `heal/2`.
  """
  @spec partition(node(), node()) :: :ok
  def partition(a, b) do
    # Two different wrong cookies: each side's handshake fails whoever dials.
    tag = System.unique_integer([:positive])
    :ok = :erpc.call(a, __MODULE__, :cut_local, [b, :"tartarus_partitioned_#{tag}_a"])
    :ok = :erpc.call(b, __MODULE__, :cut_local, [a, :"tartarus_partitioned_#{tag}_b"])
  end

  @doc "Heals a partition made by `partition/2`."
  @spec heal(node(), node()) :: :ok
  def heal(a, b) do
    # Each side on its own: a side that is down (or restarting) has nothing to heal, and
    # must not keep the other from healing.
    for {x, y} <- [{a, b}, {b, a}] do
      try do
        :erpc.call(x, __MODULE__, :heal_local, [y])
      catch
        _, _ -> :ok
      end
    end

    :ok
  end

  @doc false
  def cut_local(other, bad) do
    true = :erlang.set_cookie(other, bad)
    _ = :erlang.disconnect_node(other)
    :ok
  end

  @doc false
  def heal_local(other) do
    true = :erlang.set_cookie(other, :erlang.get_cookie())
    :ok
  end

  @doc "Stops a peer. Stopping a peer that is already gone is fine."
  @spec stop(peer()) :: :ok
  def stop(pid) do
    :peer.stop(pid)
  catch
    _, _ -> :ok
  end

  @doc false
  # Runs on the peer.
  def boot(apps, level) do
    Application.put_env(:logger, :level, level)
    {:ok, _} = Application.ensure_all_started(:logger)
    Logger.configure(level: level)

    Enum.reduce_while(apps, :ok, fn app, :ok ->
      case Application.ensure_all_started(app) do
        {:ok, _} -> {:cont, :ok}
        error -> {:halt, error}
      end
    end)
  end

  # Several BEAM nodes share this machine's cores: schedulers that busy-wait for work would
  # steal the CPU the other nodes need, so peers do not busy-wait unless asked to.
  defp scheduler_args(opts) do
    if Keyword.get(opts, :busy_wait, false),
      do: [],
      else: ["+sbwt", "none", "+sbwtdcpu", "none", "+sbwtdio", "none"]
  end

  # This node's code path minus OTP's own libraries (the peer's erl finds those itself).
  defp code_path_args do
    otp = List.to_string(:code.lib_dir())

    :code.get_path()
    |> Enum.map(&List.to_string/1)
    |> Enum.reject(&(String.starts_with?(&1, otp) or &1 == "."))
    |> Enum.flat_map(&["-pa", &1])
  end
end
