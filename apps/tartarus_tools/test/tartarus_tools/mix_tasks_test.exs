defmodule TartarusTools.MixTasksTest do
  # Every mix task of the tooling answers --help with its documentation, without running.
  use ExUnit.Case, async: false

  setup do
    Mix.shell(Mix.Shell.Process)
    on_exit(fn -> Mix.shell(Mix.Shell.IO) end)
    dir = Path.join(System.tmp_dir!(), "tartarus_tasks_#{System.unique_integer([:positive])}")
    on_exit(fn -> File.rm_rf!(dir) end)
    %{dir: dir}
  end

  @tasks [
    Mix.Tasks.Tartarus.Bench,
    Mix.Tasks.Tartarus.Chaos,
    Mix.Tasks.Tartarus.Demo,
    Mix.Tasks.Tartarus.Gen.Certs,
    Mix.Tasks.Tartarus.Node
  ]

  test "each task is named tartarus.* and answers --help and -h with its moduledoc" do
    for task <- @tasks, flag <- ["--help", "-h"] do
      name = Mix.Task.task_name(task)
      assert String.starts_with?(name, "tartarus."), name
      assert Mix.Task.get(name) == task

      # Other flags beside --help do not matter: nothing runs.
      assert :ok = task.run(["--bogus", flag])
      assert_received {:mix_shell, :info, [text]}

      first_line = task |> Mix.Task.moduledoc() |> String.split("\n") |> hd()
      assert text =~ "mix #{name} - #{Mix.Task.shortdoc(task)}"
      assert text =~ first_line
      refute_received {:mix_shell, _, _}
    end
  end

  test "a task whose options are a schema documents them and takes its defaults from it" do
    doc = Mix.Task.moduledoc(Mix.Tasks.Tartarus.Demo)
    assert doc =~ "`--out` - directory of the scenarios' reports. Defaults to `\"results/demo\"`."

    assert_raise Mix.Error,
                 "mix tartarus.demo: invalid value for --seed: expected a positive integer, got: 0",
                 fn -> Mix.Tasks.Tartarus.Demo.run(["--seed", "0"]) end

    assert_raise Mix.Error, "mix tartarus.node: missing required flag --name", fn ->
      Mix.Tasks.Tartarus.Node.run(["--host", "h1"])
    end
  end

  describe "mix tartarus.gen.certs" do
    test "writes the files", %{dir: dir} do
      Mix.Tasks.Tartarus.Gen.Certs.run(["--out", dir, "--nodes", "a, b", "--days", "2"])

      assert_received {:mix_shell, :info, [message]}
      assert message =~ "created CA #{Path.join(dir, "ca.pem")}"

      assert Enum.sort(File.ls!(dir)) ==
               ~w(a.key a.pem a.ssl_dist.conf b.key b.pem b.ssl_dist.conf ca.key ca.pem)
    end

    test "--json prints one object: the CA, each node's files, the provenance", %{dir: dir} do
      Mix.Tasks.Tartarus.Gen.Certs.run(["--out", dir, "--nodes", "a", "--json"])
      assert_received {:mix_shell, :info, [json]}
      refute_received {:mix_shell, :info, _}
      s = Tartarus.JSON.decode!(json)
      assert s["ca"] == Path.join(Path.expand(dir), "ca.pem") and s["ca_created"] == true
      assert s["nodes"]["a"] == Enum.map(~w(a.pem a.key a.ssl_dist.conf), &Path.join(Path.expand(dir), &1))
      assert Enum.all?(s["nodes"]["a"], &File.exists?/1)
      assert s["provenance"]["argv"] == ["mix", "tartarus.gen.certs", "--out", dir, "--nodes", "a", "--json"]
    end

    test "refuses bad arguments naming the flag, the expectation and the value", %{dir: dir} do
      assert_raise Mix.Error, "mix tartarus.gen.certs: missing required flag --nodes", fn ->
        Mix.Tasks.Tartarus.Gen.Certs.run(["--out", dir])
      end

      assert_raise Mix.Error,
                   ~s(mix tartarus.gen.certs: invalid value for --days: expected an integer, got: "x"),
                   fn -> Mix.Tasks.Tartarus.Gen.Certs.run(["--nodes", "a", "--days", "x"]) end

      assert_raise Mix.Error,
                   "mix tartarus.gen.certs: invalid value for --days: expected a positive integer, got: 0",
                   fn -> Mix.Tasks.Tartarus.Gen.Certs.run(["--nodes", "a", "--days", "0"]) end

      assert_raise Mix.Error, ~r/^mix tartarus.gen.certs: unknown flag --bogus/, fn ->
        Mix.Tasks.Tartarus.Gen.Certs.run(["--bogus", "1"])
      end
    end
  end
end
