Code.require_file("support/netns_bed.exs", __DIR__)

defmodule Tartarus.ReleaseTest do
  # The release (`MIX_ENV=prod mix release`, built once per run by Tartarus.NetnsBed) boots
  # from its configuration file alone, and a bad file stops the boot with one line and
  # status 1 (no root needed; the namespace bed, test/netns_test.exs, runs it on a network).
  use ExUnit.Case, async: false

  @moduletag :release
  @moduletag :tmp_dir
  @moduletag timeout: 600_000

  setup_all do
    {root, _secs} = Tartarus.NetnsBed.build_release!()
    %{bin: Path.join(root, "bin/tartarus")}
  end

  defp run(bin, config, command \\ "start") do
    System.cmd(bin, [command],
      env: [{"TARTARUS_CONFIG", config}, {"RELEASE_TMP", Path.join(Path.dirname(config), "tmp")}],
      stderr_to_stdout: true
    )
  end

  test "a bad configuration stops the boot with one clear line and status 1", %{
    bin: bin,
    tmp_dir: dir
  } do
    cases = [
      {"missing.exs", nil, "cannot read it (no such file)"},
      {"syntax.exs", "[node: \"tartarus@127.0.0.1\",", "missing terminator: ]"},
      {"nocookie.exs", "[node: \"tartarus@127.0.0.1\"]", "cookie: required without tls:"},
      {"notls.exs", "[node: \"t@127.0.0.1\", tls: [dir: \"/nonexistent\"]]",
       "tls: cert: no such file /nonexistent/t@127.0.0.1.pem"},
      {"plugin.exs", "[node: \"t@127.0.0.1\", cookie: \"c\", plugins: [x: {:nope, 1}]]",
       "plugins: x: expected {module, opts}"},
      {"key.exs", "[node: \"t@127.0.0.1\", cookie: \"c\", colour: :red]", "unknown key colour:"}
    ]

    for {file, text, expected} <- cases do
      path = Path.join(dir, file)
      if text, do: File.write!(path, text)
      {out, status} = run(bin, path)
      assert status == 1, out
      assert [line] = String.split(out, "\n", trim: true)
      assert line == "tartarus: bad configuration #{path}: " <> line_tail(line, path)
      assert line =~ expected
    end
  end

  defp line_tail(line, path),
    do: String.replace_prefix(line, "tartarus: bad configuration #{path}: ", "")

  test "the release boots from its configuration file alone", %{bin: bin, tmp_dir: dir} do
    name = "tt29rel#{System.unique_integer([:positive])}@127.0.0.1"
    path = Path.join(dir, "node.exs")

    File.write!(path, """
    [node: #{inspect(name)}, cookie: "tt29", host: "pi1", data_dir: #{inspect(Path.join(dir, "data"))},
     plugins: [temp: {:sensor, signal: [21.5]}]]
    """)

    port =
      Port.open({:spawn_executable, bin}, [
        :binary,
        :exit_status,
        :stderr_to_stdout,
        args: ["start"],
        env: [{~c"TARTARUS_CONFIG", ~c"#{path}"}, {~c"RELEASE_TMP", ~c"#{Path.join(dir, "tmp")}"}]
      ])

    {:os_pid, pid} = Port.info(port, :os_pid)

    try do
      out = await_output(port, "running", "", 180_000)

      assert out =~
               "tartarus: host {:pi1, :\"#{name}\"} running; plugins: temp (Tartarus.Plugin.SimSensor)"

      assert File.dir?(Path.join(dir, "data"))
      # The release's own rpc (plain distribution, the file's cookie) reads the plugin.
      {rpc, 0} = rpc(bin, path)
      assert rpc =~ "{:ok, 21.5}"
    after
      System.cmd("kill", ["-9", "#{pid}"], stderr_to_stdout: true)
    end
  end

  defp rpc(bin, path) do
    System.cmd(bin, ["rpc", "IO.inspect(Tartarus.read_plugin(:pi1, :temp, :value))"],
      env: [{"TARTARUS_CONFIG", path}, {"RELEASE_TMP", Path.join(Path.dirname(path), "tmp")}],
      stderr_to_stdout: true
    )
  end

  defp await_output(port, pattern, acc, timeout) do
    receive do
      {^port, {:data, data}} ->
        acc = acc <> data
        if acc =~ pattern, do: acc, else: await_output(port, pattern, acc, timeout)

      {^port, {:exit_status, s}} ->
        flunk("the release exited with #{s}:\n#{acc}")
    after
      timeout -> flunk("the release did not start:\n#{acc}")
    end
  end
end
