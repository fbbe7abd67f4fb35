defmodule Tartarus.ReleaseSession do
  @moduledoc """
  What the release's tests do to a running release, on this machine (test/release_test.exs)
  and on the namespace bed (test/netns_test.exs): the documented configuration adapted in
  paths and names (`from_example!/2`), an HM-10 on a socat pseudo-terminal (`socat!/1`), a
  person's terminal (`pty!/2`, `script` giving the command a pty), and waiting for output.

  Every process started here is one this test started, ended by its pid: `stop_port/1`,
  `stop_ptys/0` (each terminal with what it runs).
  """

  import ExUnit.Assertions

  @doc """
  Writes `rel/node.exs.example` with each `{from, to}` of `replacements` made into
  `dir/name` and returns its path; raises if a `from` is not in the example (the example
  changed: the test no longer runs what the documentation says).
  """
  def from_example!(dir, replacements, name \\ "node.exs") do
    text =
      Enum.reduce(replacements, File.read!("rel/node.exs.example"), fn {from, to}, text ->
        if not String.contains?(text, from),
          do: raise("rel/node.exs.example has no #{inspect(from)}")

        String.replace(text, from, to)
      end)

    path = Path.join(dir, name)
    File.write!(path, text)
    path
  end

  @doc """
  The example's replacements for a node of name `name` whose certificates are in `certs`
  (operator certificate `operator`), neighbour `{host, node}`, HM-10 on `tty`, data under
  `dir`, the dashboard on a free port of the loopback.
  """
  def example_paths(name, certs, operator, {nhost, nnode}, tty, dir) do
    [
      {~s("tartarus@pi1.local"), inspect(name)},
      {~s(pi2: "tartarus@pi2.local"), "#{nhost}: #{inspect(nnode)}"},
      {~s(tls: [dir: "/etc/tartarus/certs"]),
       "tls: [dir: #{inspect(certs)}, operator: #{inspect(operator)}]"},
      {~s("/dev/serial0"), inspect(tty)},
      {~s("/var/lib/tartarus/host"), inspect(Path.join(dir, "data"))},
      # The dashboard on a free port of the loopback (4000 may be taken on a test machine).
      {~s(port: 4000, bind: "0.0.0.0"), ~s(port: 0, bind: "127.0.0.1")}
    ]
  end

  @doc "The beacon the tests' HM-10 hears (one iBeacon; its tag is `TartarusLats.Beacon.tag_id/1`)."
  def beacon do
    %TartarusLats.Beacon{
      uuid: "74278bdab64445208f0c720eaf059935",
      major: 1234,
      minor: 1111,
      tx_power: -59,
      rssi: -61
    }
  end

  @doc "Feeds one scan of `beacon/0` to the HM-10 on `socat` (a `socat!/1` port)."
  def hear(socat), do: Port.command(socat, TartarusLats.HM10.encode_scan([beacon()]))

  @doc """
  The expression (for `bin/tartarus rpc`) that releases Where am I for `tag` on host `host`
  of the node and prints its answer (`{:in_zone, host}` once the node has heard the tag).
  """
  def where_am_i(host, tag) do
    "{:ok, id} = Tartarus.create_mobile_agent(#{inspect(host)}, TartarusLats.Query.WhereAmI, " <>
      "%{tag: #{inspect(tag)}, label: nil, report: false, cloud: :per_node, repair: false}, owner: self()); " <>
      "receive do {:tartarus_result, ^id, r} -> IO.inspect(r.answer) after 10_000 -> IO.puts(:none) end"
  end

  @doc """
  A socat pseudo-terminal linked at `link` (no commas in it: socat's address syntax), its
  other end this test's port. Raises when socat is not installed.
  """
  def socat!(link) do
    exe =
      System.find_executable("socat") ||
        flunk("socat is not installed (scripts/test installs it)")

    port =
      Port.open({:spawn_executable, exe}, [
        :binary,
        :exit_status,
        args: ["pty,raw,echo=0,link=#{link}", "STDIO"]
      ])

    assert eventually(fn -> File.exists?(link) end)
    port
  end

  @doc """
  A terminal session: `script` gives `command` (a shell command line) a pty, as a person's
  terminal would; `env` is added to its environment. Ended, with what it runs, by
  `stop_ptys/0`, whatever happened.
  """
  def pty!(command, env) do
    port =
      Port.open({:spawn_executable, System.find_executable("script")}, [
        :binary,
        :exit_status,
        :stderr_to_stdout,
        args: ["-qfc", command, "/dev/null"],
        env: for({k, v} <- env, do: {~c"#{k}", if(v, do: ~c"#{v}", else: false)})
      ])

    {:os_pid, pid} = Port.info(port, :os_pid)
    Process.put(:ptys, [pid | Process.get(:ptys, [])])
    port
  end

  @doc "Ends every terminal session `pty!/2` started in this process, and what it runs."
  def stop_ptys do
    for pid <- Process.get(:ptys, []), do: kill_tree(pid)
    Process.delete(:ptys)
    :ok
  end

  # The process and its descendants (script -> sh -> the VM), by their pids.
  defp kill_tree(pid) do
    {children, _} = System.cmd("pgrep", ["-P", "#{pid}"], stderr_to_stdout: true)
    for child <- String.split(children, "\n", trim: true), do: kill_tree(child)
    System.cmd("kill", ["-9", "#{pid}"], stderr_to_stdout: true)
  end

  @doc "Waits (up to 2 min) until the session's output matches `pattern`; returns the output."
  def await_pty(port, pattern, acc \\ "") do
    receive do
      {^port, {:data, data}} ->
        acc = acc <> data
        if acc =~ pattern, do: acc, else: await_pty(port, pattern, acc)

      {^port, {:exit_status, s}} ->
        flunk("the session exited with #{s}:\n#{acc}")
    after
      120_000 -> flunk("no #{inspect(pattern)} in the session:\n#{acc}")
    end
  end

  @doc "Everything the session prints until it exits (up to 2 min): `{output, status}`."
  def pty_exit(port, acc \\ "") do
    receive do
      {^port, {:data, data}} -> pty_exit(port, acc <> data)
      {^port, {:exit_status, s}} -> {acc, s}
    after
      120_000 -> flunk("the session did not exit:\n#{acc}")
    end
  end

  @doc "Ctrl-G q: the shell's own VM quits (the node goes on)."
  def quit_pty(port) do
    Port.command(port, "\a")
    Process.sleep(300)
    Port.command(port, "q\n")

    receive do
      {^port, {:exit_status, _}} -> :ok
    after
      30_000 -> stop_port(port)
    end
  end

  @doc "SIGKILLs the OS process of `port`, if it still runs."
  def stop_port(port) do
    case Port.info(port, :os_pid) do
      {:os_pid, pid} -> System.cmd("kill", ["-9", "#{pid}"], stderr_to_stdout: true)
      nil -> :ok
    end

    :ok
  end

  @doc "Whether `fun` returns true within `tries` tries, half a second apart."
  def eventually(fun, tries \\ 60) do
    cond do
      fun.() -> true
      tries == 0 -> false
      true -> Process.sleep(500) && eventually(fun, tries - 1)
    end
  end

  @doc "Waits (up to `timeout` ms) until the release on `port` printed `pattern`; returns its output."
  def await_output(port, pattern, acc, timeout) do
    if acc =~ pattern do
      acc
    else
      receive do
        {^port, {:data, data}} ->
          await_output(port, pattern, acc <> data, timeout)

        {^port, {:exit_status, s}} ->
          flunk("the release exited with #{s}:\n#{acc}")
      after
        timeout -> flunk("the release did not start:\n#{acc}")
      end
    end
  end
end
