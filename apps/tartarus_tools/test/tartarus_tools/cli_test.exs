defmodule Tartarus.CLITest do
  use ExUnit.Case, async: true
  doctest TartarusTools.CLI
  doctest TartarusTools.Provenance
  doctest Mix.Tasks.Tartarus.Chaos

  test "unknown flags, missing values and stray arguments are refused naming the task and flag" do
    assert_raise Mix.Error,
                 "mix tartarus.x: unknown flag --nope; see `mix help tartarus.x` or --help",
                 fn ->
                   TartarusTools.CLI.parse!(["--nope"], [hosts: :integer], "tartarus.x")
                 end

    assert_raise Mix.Error, "mix tartarus.x: missing value for --hosts: expected an integer", fn ->
      TartarusTools.CLI.parse!(["--hosts"], [hosts: :integer], "tartarus.x")
    end

    assert_raise Mix.Error, ~r/unexpected argument extra/, fn ->
      TartarusTools.CLI.parse!(["extra"], [hosts: :integer], "tartarus.x")
    end

    assert {[hosts: 3], ["run"]} =
             TartarusTools.CLI.parse!(["run", "--hosts", "3"], [hosts: :integer], "tartarus.x",
               args: true
             )
  end

  test "error!/2 turns an experiment's message into one line naming the flag" do
    assert_raise Mix.Error,
                 "mix tartarus.x: invalid value for --state-bytes: expected a positive integer, got: 0",
                 fn ->
                   TartarusTools.CLI.error!(
                     "tartarus.x",
                     "invalid options given to TartarusX.Experiment.run/1 for key :state_bytes: " <>
                       "expected a positive integer, got: 0"
                   )
                 end

    assert_raise Mix.Error, "mix tartarus.x: missing required flag --name", fn ->
      TartarusTools.CLI.error!("tartarus.x", "required option :name not given to mix tartarus.x")
    end

    assert_raise Mix.Error, "mix tartarus.x: {:bad, 1}", fn ->
      TartarusTools.CLI.error!("tartarus.x", {:bad, 1})
    end
  end

  test "checks name the flag, the expectation and the value" do
    assert_raise Mix.Error,
                 "mix tartarus.x: --state-bytes must be a positive integer, got: 0",
                 fn ->
                   TartarusTools.CLI.positive!([state_bytes: 0], [:state_bytes], "tartarus.x")
                 end

    assert_raise Mix.Error,
                 "mix tartarus.x: --p must be a number between 0 and 1, got: 1.5",
                 fn ->
                   TartarusTools.CLI.probability!([p: 1.5], [:p], "tartarus.x")
                 end

    assert :ok = TartarusTools.CLI.non_negative!([kills: 0], [:kills], "tartarus.x")

    assert_raise Mix.Error, "mix tartarus.x: --mode must be virtual or peer, got: cloud", fn ->
      TartarusTools.CLI.choice!("cloud", [:virtual, :peer], :mode, "tartarus.x", :virtual)
    end
  end

  test "report prints one JSON object as the last line and can write it to a file" do
    path = Path.join(System.tmp_dir!(), "cli_#{System.unique_integer([:positive])}.json")
    Mix.shell(Mix.Shell.Process)

    try do
      TartarusTools.CLI.report(%{b: 2, a: "x"}, json: true, out_file: path)
      assert_received {:mix_shell, :info, [json]}
      assert {:ok, %{"a" => "x", "b" => 2}} = Tartarus.JSON.decode(json)
      assert File.read!(path) == json <> "\n"
      assert %{"provenance" => %{"argv" => _, "git_commit" => _}} = Tartarus.JSON.decode!(json)

      TartarusTools.CLI.report(%{b: %{"10" => 0.30000000000000004, "2" => nil}, a: "x"}, [])
      assert_received {:mix_shell, :info, ["  a: x"]}
      assert_received {:mix_shell, :info, ["  b: {2: -, 10: 0.3}"]}
    after
      Mix.shell(Mix.Shell.IO)
      File.rm(path)
    end
  end
end
