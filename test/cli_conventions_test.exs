defmodule TartarusCLIConventionsTest do
  # One CLI convention across the umbrella's mix tasks (issue 31): a flag with no value, a
  # bad value and an unknown flag each end the task with one line naming the task and the
  # flag as typed (`--nodes`, not `:nodes`), and Mix turns that `Mix.Error` into exit
  # status 1 without a stack trace; a `--json` summary and its `summary.json` carry what
  # made them (argv, commit, versions, date, machine).
  use ExUnit.Case, async: false

  @moduletag :cli

  @tmp Path.join(System.tmp_dir!(), "tartarus_cli_conventions")

  setup do
    Mix.shell(Mix.Shell.Process)
    on_exit(fn -> Mix.shell(Mix.Shell.IO) end)
    :ok
  end

  # {task, the flag checked, argv with its value missing, argv with a bad value}
  @cases [
    {"tartarus.arena", "--seed", ~w(--seed), ~w(--seed 0)},
    {"tartarus.bench", "--rounds", ~w(migration --rounds), ~w(migration --rounds 0)},
    {"tartarus.chaos", "--nodes", ~w(--nodes), ~w(--nodes 1)},
    {"tartarus.dashboard.bench", "--rounds", ~w(--rounds), ~w(--rounds 0)},
    {"tartarus.demo", "--seed", ~w(--seed), ~w(--seed 0)},
    {"tartarus.emu", "--hosts", ~w(--hosts), ~w(--hosts 0)},
    {"tartarus.evolve", "--seeds", ~w(--seeds), ~w(--seeds 0)},
    {"tartarus.gen.certs", "--days", ~w(--nodes a --days), ~w(--nodes a --days 0)},
    {"tartarus.lats", "--nodes", ~w(--nodes), ~w(--nodes 0)},
    {"tartarus.lats.calibrate", "--kind", ~w(--kind), ~w(--kind bogus)},
    {"tartarus.node", "--speed", ~w(--name n --speed), ~w(--name n --speed 0)},
    {"tartarus.pfa", "--laps", ~w(--laps), ~w(--laps 0)},
    {"tartarus.roadblock", "--steps", ~w(--steps), ~w(--steps 0)},
    {"tartarus.select", "--seeds", ~w(--seeds), ~w(--seeds 0)},
    {"tartarus.warehouse", "--robots", ~w(--robots), ~w(--robots 0)}
  ]

  defp error(task, argv) do
    module = Mix.Task.get!(task)

    try do
      module.run(argv)
      flunk("mix #{task} #{Enum.join(argv, " ")} did not fail")
    rescue
      e in Mix.Error -> e.message
    end
  end

  defp assert_one_line(message, task, flag, what) do
    assert String.starts_with?(message, "mix #{task}: "), message
    refute message =~ "\n", message
    assert message =~ flag, message
    assert message =~ what, message
    # No module, function or option key of the code behind the flag.
    refute message =~ ~r/[A-Z]\w+\.\w+(\.\w+)*\/\d|\s:[a-z_]+\b/, message
  end

  test "every mix task is covered" do
    tasks =
      for {task, _} <- Mix.Task.load_all() |> Enum.map(&{Mix.Task.task_name(&1), &1}),
          String.starts_with?(task, "tartarus."),
          do: task

    assert Enum.sort(tasks) == Enum.sort(for {task, _, _, _} <- @cases, do: task)
  end

  test "the README's task table lists every task" do
    rows =
      for [task] <-
            Regex.scan(~r/^\| `mix (tartarus\.[\w.]+)` \|/m, File.read!("README.md"),
              capture: :all_but_first
            ),
          do: task

    assert Enum.sort(rows) == Enum.sort(for {task, _, _, _} <- @cases, do: task)
  end

  test "a flag with no value: one line naming it, what is missing" do
    for {task, flag, missing, _bad} <- @cases do
      assert_one_line(error(task, missing), task, flag, "missing value for #{flag}")
    end
  end

  test "a bad value: one line naming the flag and the value" do
    for {task, flag, _missing, bad} <- @cases do
      message = error(task, bad)
      assert_one_line(message, task, flag, List.last(bad))
    end
  end

  test "an unknown flag: one line naming it" do
    for {task, _, _, _} <- @cases do
      assert_one_line(error(task, ~w(--bogus 1)), task, "--bogus", "unknown flag")
    end
  end

  # {task, argv before --out, what --out names: a directory or a file}
  @outs [
    {"tartarus.arena", [], :dir},
    {"tartarus.bench", ~w(migration), :file},
    {"tartarus.chaos", [], :file},
    {"tartarus.dashboard.bench", [], :file},
    {"tartarus.demo", [], :dir},
    {"tartarus.emu", [], :dir},
    {"tartarus.evolve", [], :dir},
    {"tartarus.gen.certs", ~w(--nodes a), :dir},
    {"tartarus.lats", [], :dir},
    {"tartarus.lats.calibrate", ~w(--fingerprints x --devices y), :file},
    {"tartarus.pfa", [], :dir},
    {"tartarus.roadblock", ~w(--auto), :dir},
    {"tartarus.select", [], :dir},
    {"tartarus.warehouse", [], :dir}
  ]

  # (Issue 45) An --out that cannot be written is refused before anything runs: no stack
  # trace after a whole run.
  test "an --out that cannot be written: one line naming it, before the run" do
    File.mkdir_p!(@tmp)
    file = Path.join(@tmp, "a_file_#{System.unique_integer([:positive])}")
    File.write!(file, "")
    on_exit(fn -> File.rm(file) end)

    for {task, argv, kind} <- @outs do
      # Under a regular file, nothing can be created.
      under = Path.join(file, "results")
      message = error(task, argv ++ ["--out", under])

      assert_one_line(
        message,
        task,
        "--out #{under}",
        "cannot be created: #{file} is not a directory"
      )

      # A directory where a file is wanted, a file where a directory is.
      {path, what} =
        if kind == :dir,
          do: {file, "exists and is not a directory"},
          else: {@tmp, "is a directory"}

      assert_one_line(error(task, argv ++ ["--out=#{path}"]), task, "--out #{path}", what)
    end

    # Every task that takes --out is covered (tartarus.node has none).
    assert Enum.sort(for {task, _, _} <- @outs, do: task) ==
             Enum.sort(for {task, _, _, _} <- @cases, task != "tartarus.node", do: task)
  end

  test "an --out that can be written is taken and nothing is left behind by the check" do
    File.mkdir_p!(@tmp)
    before = File.ls!(@tmp)

    assert TartarusTools.CLI.out!(["--out", Path.join(@tmp, "new/sub")], :dir, "tartarus.x") ==
             :ok

    assert TartarusTools.CLI.out!(["--out", Path.join(@tmp, "f.json")], :file, "tartarus.x") ==
             :ok

    assert TartarusTools.CLI.out!(["--out", @tmp], :dir, "tartarus.x") == :ok
    assert File.ls!(@tmp) == before
  end

  # (Issue 45) {task, argv, flag, the range named}: a value that cannot lead to a result is
  # refused before the run, naming the valid range.
  @ranges [
    {"tartarus.select", ~w(--experiment danger --share 2), "--share",
     "a number from 0 to 1, got: 2.0"},
    {"tartarus.select", ~w(--eta 1.5), "--eta", "a number between 0 and 1, got: 1.5"},
    {"tartarus.warehouse", ~w(--scale -1), "--scale", "a number from 0.0001 to 1000, got: -1.0"},
    {"tartarus.lats", ~w(--noise-db -3), "--noise-db", "a number from 0 to 40, got: -3.0"},
    {"tartarus.evolve", ~w(--sigma-max 0), "--sigma-max", "a number from 0.001 to 100, got: 0.0"},
    {"tartarus.pfa", ~w(--stuck-after 0), "--stuck-after", "a number from 0.1 to 3600, got: 0.0"},
    {"tartarus.pfa", ~w(--lost-penalty -1), "--lost-penalty",
     "a number from 0 to 3600, got: -1.0"}
  ]

  test "a value outside its range: one line naming the flag and the range, before the run" do
    for {task, argv, flag, range} <- @ranges do
      assert_one_line(
        error(task, argv),
        task,
        flag,
        "invalid value for #{flag}: expected #{range}"
      )
    end
  end

  test "the usage line brackets a flag that has a default" do
    for task <- ["tartarus.warehouse", "tartarus.select", "tartarus.evolve"] do
      doc = Mix.Task.moduledoc(Mix.Task.get!(task))
      [usage] = Regex.run(~r/^\s+mix #{task} .*$/m, doc)
      assert usage =~ "mix #{task} [--experiment ", usage
    end
  end

  test "the cases of the issue: a missing file" do
    message = error("tartarus.emu", ~w(--topology /nonexistent/topology.txt))
    assert_one_line(message, "tartarus.emu", "--topology", "file not found")
  end

  test "--help shows the flags as typed" do
    for task <- ["tartarus.demo", "tartarus.node", "tartarus.gen.certs", "tartarus.select"] do
      Mix.Task.get!(task).run(["--help"])
      assert_received {:mix_shell, :info, [text]}
      refute text =~ ~r/^\s*\* `:/m, "#{task}: #{text}"
    end

    Mix.Task.get!("tartarus.demo").run(["--help"])
    assert_received {:mix_shell, :info, [text]}
    assert text =~ "* `--seed`"
  end

  # From a shell, as a person runs them: tasks that start the applications before they can
  # tell the error (the demo knows its sections once they are loaded) run there, since
  # `app.start` inside this test run drops the tests after it.
  defp shell(argv) do
    System.cmd("mix", argv, stderr_to_stdout: true, env: [{"MIX_ENV", "test"}])
  end

  test "from the shell: exit status 1, the one line, no stack trace" do
    {out, status} = shell(~w(tartarus.chaos --nodes 1))
    assert status == 1
    assert out =~ "** (Mix) mix tartarus.chaos: --nodes must be at least 2, got: 1\n"
    refute out =~ "(elixir "
    refute out =~ "stacktrace"
  end

  test "from the shell: a share out of range and an unwritable --out end in one line, exit 1" do
    file = Path.join(System.tmp_dir!(), "tartarus_cli_out_#{System.unique_integer([:positive])}")
    File.write!(file, "")
    on_exit(fn -> File.rm(file) end)

    for {argv, line} <- [
          {~w(tartarus.select --experiment danger --share 2),
           "** (Mix) mix tartarus.select: invalid value for --share: expected a number from 0 to 1, got: 2.0\n"},
          {~w(tartarus.select --experiment danger --out #{file}/x),
           "** (Mix) mix tartarus.select: --out #{file}/x: cannot be created: #{file} is not a directory\n"}
        ] do
      {out, status} = shell(argv)
      assert status == 1, out
      assert out =~ line
      refute out =~ "(elixir "
      refute out =~ "select: experiment"
    end
  end

  test "--only refuses an unknown section and lists them" do
    {out, status} = shell(~w(tartarus.demo --only nope))
    assert status == 1
    [line] = out |> String.split("\n", trim: true) |> Enum.filter(&(&1 =~ "** (Mix)"))

    assert line =~
             ~s(mix tartarus.demo: --only "nope" names no section; the sections are: platform, )

    assert line =~ "emulation" and line =~ "lats" and line =~ "warehouse"
    refute out =~ "(elixir "
  end

  test "--json and summary.json carry the provenance" do
    out = Path.join(@tmp, "emu_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(out) end)
    argv = ~w(--hosts 4 --agents 1 --steps 3 --seed 1 --json --out #{out})

    # From a shell (see shell/1); stdout alone: the JSON is its last line.
    {stdout, 0} = System.cmd("mix", ["tartarus.emu" | argv], env: [{"MIX_ENV", "test"}])
    json = stdout |> String.split("\n", trim: true) |> List.last()
    summary = Tartarus.JSON.decode!(json)
    from_file = out |> Path.join("summary.json") |> File.read!() |> Tartarus.JSON.decode!()

    for p <- [summary["provenance"], from_file["provenance"]] do
      assert Enum.sort(Map.keys(p)) == ~w(argv date elixir git_commit git_dirty machine otp)
      assert p["argv"] == ["mix", "tartarus.emu" | argv]
      assert p["elixir"] == System.version()
      assert p["otp"] =~ ~r/^#{System.otp_release()}/
      assert {:ok, _, 0} = DateTime.from_iso8601(p["date"])
      assert p["git_commit"] =~ ~r/^([0-9a-f]{40}|unknown)$/
      assert p["git_dirty"] in [true, false, nil]
      assert p["machine"]["schedulers"] == System.schedulers_online()
    end

    assert File.read!(Path.join(out, "summary.md")) =~ "| argv | `mix tartarus.emu --hosts 4"
  end
end
