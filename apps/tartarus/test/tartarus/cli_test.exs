defmodule Tartarus.CLITest do
  use ExUnit.Case, async: true
  doctest Tartarus.CLI

  test "unknown flags and stray arguments are refused naming the task" do
    assert_raise Mix.Error,
                 "mix tartarus.x: invalid arguments --nope; see `mix help tartarus.x`",
                 fn ->
                   Tartarus.CLI.parse!(["--nope"], [hosts: :integer], "tartarus.x")
                 end

    assert_raise Mix.Error, ~r/invalid arguments extra/, fn ->
      Tartarus.CLI.parse!(["extra"], [hosts: :integer], "tartarus.x")
    end

    assert {[hosts: 3], ["run"]} =
             Tartarus.CLI.parse!(["run", "--hosts", "3"], [hosts: :integer], "tartarus.x",
               args: true
             )
  end

  test "checks name the flag, the expectation and the value" do
    assert_raise Mix.Error,
                 "mix tartarus.x: --state-bytes must be a positive integer, got: 0",
                 fn ->
                   Tartarus.CLI.positive!([state_bytes: 0], [:state_bytes], "tartarus.x")
                 end

    assert_raise Mix.Error,
                 "mix tartarus.x: --p must be a number between 0 and 1, got: 1.5",
                 fn ->
                   Tartarus.CLI.probability!([p: 1.5], [:p], "tartarus.x")
                 end

    assert :ok = Tartarus.CLI.non_negative!([kills: 0], [:kills], "tartarus.x")

    assert_raise Mix.Error, "mix tartarus.x: --mode must be virtual or peer, got: cloud", fn ->
      Tartarus.CLI.choice!("cloud", [:virtual, :peer], :mode, "tartarus.x", :virtual)
    end
  end

  test "report prints one JSON object as the last line and can write it to a file" do
    path = Path.join(System.tmp_dir!(), "cli_#{System.unique_integer([:positive])}.json")
    Mix.shell(Mix.Shell.Process)

    try do
      Tartarus.CLI.report(%{b: 2, a: "x"}, json: true, out_file: path)
      assert_received {:mix_shell, :info, [json]}
      assert {:ok, %{"a" => "x", "b" => 2}} = Tartarus.JSON.decode(json)
      assert File.read!(path) == json <> "\n"
    after
      Mix.shell(Mix.Shell.IO)
      File.rm(path)
    end
  end
end
