defmodule TartarusRoadblockTest do
  use ExUnit.Case, async: false

  import Tartarus.TestSupport

  doctest TartarusRoadblock
  doctest TartarusRoadblock.Site
  doctest TartarusRoadblock.RescueProgram

  @outcome [
    :rescued,
    :chosen_robot,
    :santa_arrived,
    :agent_hops,
    :seconds,
    :santa_arrival_s,
    :santa_stopped_s,
    :rescue_done_s,
    :claus_docked,
    :block,
    :block_final,
    :candidates,
    :hosts_visited
  ]

  test "on the dashboard: the panel shows the snapshot while the run waits, and its button releases the rescue agent" do
    {:ok, l} = :gen_tcp.listen(0, [])
    {:ok, port} = :inet.port(l)
    :gen_tcp.close(l)
    token = "roadblock-panel-test-token"
    url = "http://127.0.0.1:#{port}/api/panels"

    {:ok, _} = TartarusRoadblock.start(seed: 1, out: false, dashboard: [port: port, token: token])

    # The panel offers its button once the run waits.
    panel = eventually(fn -> offering(first_panel(url)) end, 60_000)
    assert panel["title"] =~ "Roadblock"
    assert [%{"action" => "release"}] = panel["actions"]
    assert ["Santa", "stopped", _] = Enum.find(panel["rows"], &(hd(&1) == "Santa"))
    "data:image/png;base64," <> b64 = panel["image"]
    assert <<137, "PNG", _::binary>> = Base.decode64!(b64)

    req =
      {String.to_charlist(url <> "/roadblock/release"),
       [{~c"authorization", ~c"Bearer " ++ String.to_charlist(token)}], ~c"application/json",
       "{}"}

    {:ok, {{_, 200, _}, _, body}} =
      :httpc.request(:post, req, [timeout: 30_000], body_format: :binary)

    assert %{"ok" => true, "result" => agent} = Tartarus.JSON.decode!(body)
    assert is_binary(agent)

    {:ok, %{summary: s}} = TartarusRoadblock.await()
    assert s.rescued and s.chosen_robot == "claus" and s.santa_arrived
    # Nothing waits any more: the button's action is refused.
    assert TartarusRoadblock.Panel.act(:ets.new(:rb_none, []), "release", %{}) ==
             {:error, :not_waiting}
  end

  @tag :tmp_dir
  test "auto mode, virtual hosts: Claus is chosen, the block removed, Santa arrives", %{
    tmp_dir: dir
  } do
    {:ok, %{summary: s, files: files}} = TartarusRoadblock.run(seed: 1, out: dir)
    assert s.rescued
    assert s.chosen_robot == "claus"
    assert s.santa_arrived
    assert s.claus_docked
    assert s.hosts_visited == 13
    # pc7 to pc11 is 4 hops; foraging every host costs more
    assert s.agent_hops > 4
    # Santa waited for the rescue and arrived after the block was off the path
    assert s.santa_stopped_s > 0 and s.santa_arrival_s < s.seconds
    # the block is off the path, not in Claus's claws
    assert abs(s.block_final.y - 0.8) > 0.15
    # the paths name the block once ("block", not "block block")
    paths = File.read!(Path.join(dir, "trajectories.svg"))
    refute paths =~ "block block"
    assert paths =~ ~r/<text[^>]*>block<\/text>/

    assert [
             %{robot: "santa"},
             %{robot: "claus", capabilities: claus},
             %{robot: "rudolph", capabilities: rudolph}
           ] = s.candidates

    assert :claws in claus and :claws not in rudolph and :pusher in rudolph

    for f <- ~w(snapshot.png trajectories.svg timeline.csv timeline.svg summary.json) do
      path = Path.join(dir, f)
      assert path in files or File.exists?(path), f
    end

    assert {320, 240, _} = TartarusArena.PNG.decode(File.read!(Path.join(dir, "snapshot.png")))
    csv = File.read!(Path.join(dir, "timeline.csv"))
    assert csv =~ "snapshot taken"
    assert csv =~ "chooses claus"
    assert csv =~ "arrives at B"
    assert File.read!(Path.join(dir, "trajectories.svg")) =~ "<svg"
  end

  @tag :tmp_dir
  test "mix tartarus.roadblock cut short by --steps says what did not happen, no blanks", %{
    tmp_dir: dir
  } do
    Mix.shell(Mix.Shell.Process)
    on_exit(fn -> Mix.shell(Mix.Shell.IO) end)
    Mix.Tasks.Tartarus.Roadblock.run(~w(--auto --steps 10 --out #{dir}))
    assert_received {:mix_shell, :info, ["roadblock: seed 1, virtual hosts..."]}
    assert_received {:mix_shell, :info, [text]}

    assert text =~
             "no robot chosen: the run ended at 0.5 s of arena time (10 steps of 0.05 s), before the rescue"

    assert text =~ "Santa did not arrive (stopped 0.0 s); rescue agent 0 hops over 0 hosts"
    refute text =~ ~r/ at  s|by  \(|false at/
  end

  test "the same seed gives the same run; another seed puts the block elsewhere" do
    {:ok, %{summary: a}} = TartarusRoadblock.run(seed: 5, out: false)
    {:ok, %{summary: b}} = TartarusRoadblock.run(seed: 5, out: false)
    {:ok, %{summary: c}} = TartarusRoadblock.run(seed: 6, out: false)
    assert Map.take(a, @outcome) == Map.take(b, @outcome)
    assert a.block != c.block
    assert c.rescued and c.chosen_robot == "claus" and c.santa_arrived
  end

  test "an administrator who asks for a pusher gets Rudolph, who cannot lift the block" do
    # the administrator decides what the robot must have; the agent compares capabilities
    {:ok, _} = TartarusRoadblock.start(seed: 2, out: false, steps: 900)
    wait_until_blocked()
    assert {:ok, id} = TartarusRoadblock.release_rescue(requirement: [:drive, :pusher])
    assert is_binary(id)
    assert {:ok, %{summary: s}} = TartarusRoadblock.await()
    assert s.chosen_robot == "rudolph"
    refute s.rescued
    refute s.santa_arrived
  end

  test "the administrator in iex: start, snapshot, release_rescue, await" do
    tmp = Path.join(System.tmp_dir!(), "roadblock_iex_#{System.unique_integer([:positive])}.png")
    assert TartarusRoadblock.release_rescue() == {:error, :no_run_waiting}
    {:ok, _pid} = TartarusRoadblock.start(seed: 1, out: false)
    wait_until_blocked()
    assert {:ok, report} = TartarusRoadblock.snapshot(tmp)
    assert report.robot == "santa"
    assert {320, 240, _} = TartarusArena.PNG.decode(File.read!(tmp))
    assert {:ok, id} = TartarusRoadblock.release_rescue()
    assert is_binary(id)
    assert {:ok, %{summary: s}} = TartarusRoadblock.await()
    assert s.rescued and s.chosen_robot == "claus" and s.santa_arrived
    {:ok, %{summary: auto}} = TartarusRoadblock.run(seed: 1, out: false)
    assert Map.take(s, @outcome) == Map.take(auto, @outcome)
  end

  test "bad options are refused with the key, what was expected and what arrived" do
    assert {:error, message} = TartarusRoadblock.run(mode: :cloud)
    assert message =~ "mode"
    assert message =~ "cloud"
  end

  defp first_panel(url) do
    case TartarusDashboard.http_get(url, 5_000) do
      {:ok, 200, body} ->
        body |> Tartarus.JSON.decode!() |> Map.get("panels") |> List.first()

      _ ->
        nil
    end
  end

  defp offering(panel), do: panel && panel["actions"] != [] && panel

  # The run waits for the administrator once its driver is registered.
  defp wait_until_blocked,
    do: eventually(fn -> Process.whereis(TartarusRoadblock.Driver) end, 60_000)
end
