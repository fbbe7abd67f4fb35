defmodule TartarusArena.SensitivityTest do
  # Not async: its last test runs the mix task, whose `Mix.Task.run("app.start")` may change
  # the VM's working directory for a moment (Mix visiting the umbrella's projects) while
  # ExUnit still loads this app's test files by relative path: a CI run failed so
  # (`{:error, :enoent}` requiring test/tartarus_arena/server_test.exs from the umbrella's
  # root). Every other test file that runs a mix task is synchronous already.
  use ExUnit.Case, async: false

  alias TartarusArena.{Paths, Run, Sensitivity, World}

  doctest Sensitivity

  # a world with one straight line along y = 1 and a robot whose left sensor is at
  # lateral offset `off` from it
  defp on_line(opts, off) do
    w =
      World.new([noise: :none] ++ opts)
      |> World.add_line([{0.5, 1.0}, {2.5, 1.0}])
      # the left sensor is 6 cm ahead and 2.5 cm left of the centre
      |> World.add_robot(:r, x: 1.5, y: 1.0 - 0.025 + off, theta: 0.0)

    {%{line: {l, _}}, _} = World.sense(w, :r, [:line])
    l
  end

  test "a sensor footprint: darker over the line's edge, never fully black over a 2 cm line" do
    # the 8 mm spot: black (12) on the line, white (60) 2 cm off its centre
    assert on_line([], 0.0) == 12 and on_line([], 0.02) == 60
    # a 3 cm disc covers ~78 % of itself with a 2 cm line at its centre
    centre = on_line([line_footprint: 0.015], 0.0)
    assert centre > 12 and centre < 36
    # 2 cm off the centre the spot reads white, the disc still sees some of the line
    assert on_line([line_footprint: 0.015], 0.02) < 60
    assert on_line([line_footprint: 0.015], 0.05) == 60
    assert_raise ArgumentError, ~r/line_footprint/, fn -> World.new(line_footprint: -1) end
  end

  test "an acceleration limit: a robot starts slowly, reaches its speed, and is at rest where it is placed" do
    drive = fn w, n ->
      Enum.reduce(1..n, w, fn _, w -> World.step(w, %{r: {1.0, 1.0}}, 0.02) end)
    end

    free = World.new(noise: :none) |> World.add_robot(:r, x: 1.0, y: 1.0)
    slow = World.new(noise: :none) |> World.add_robot(:r, x: 1.0, y: 1.0, accel: 1.0)
    # 0.1 s from rest: 2.5 cm without a limit, 0.5 a t^2 ~ 0.6 cm with 1 m/s^2
    {xf, _, _} = World.pose(drive.(free, 5), :r)
    {xs, _, _} = World.pose(drive.(slow, 5), :r)
    assert_in_delta xf - 1.0, 0.025, 1.0e-9
    assert xs - 1.0 < 0.01
    # after 0.5 s both move at the top speed
    w = drive.(slow, 25)
    {x1, _, _} = World.pose(w, :r)
    {x2, _, _} = World.pose(drive.(w, 5), :r)
    assert_in_delta x2 - x1, 0.025, 1.0e-9
    # placed elsewhere, it starts from rest again
    w = World.place(w, :r, {1.0, 2.0, 0.0})
    {x3, _, _} = World.pose(drive.(w, 5), :r)
    assert x3 - 1.0 < 0.01
  end

  test "rounded corners: no vertex turns more than 30 degrees, the sub-paths keep their ends on the straights" do
    for id <- [1, 2] do
      sharp = Paths.path(id, 3)
      round = Paths.path(id, 3, corner_radius: 0.05)
      assert max_turn(sharp) > 89
      assert max_turn(round) < 30
      assert Enum.map(round.subpaths, & &1.type) == Enum.map(sharp.subpaths, & &1.type)
      assert round.length < sharp.length
      # the first sub-path (a straight) is untouched
      assert hd(round.subpaths).to == hd(sharp.subpaths).to
    end

    assert_raise ArgumentError, ~r/does not fit/, fn -> Paths.path(2, 3, corner_radius: 0.2) end
  end

  test "A2, which loses sp-d's tips in the kinematic arena, completes them with rounded corners" do
    sharp = Paths.path(2, 4)
    round = Paths.path(2, 4, corner_radius: 0.05)
    d = Enum.find_index(sharp.subpaths, &(&1.type == :sp_d))
    refute Run.subpath(TartarusArena.PFA.A2, sharp, d, seed: 4).completed
    assert Run.subpath(TartarusArena.PFA.A2, round, d, seed: 4).completed
  end

  defp max_turn(path) do
    pts = path.points
    n = length(pts)

    for i <- 0..(n - 1) do
      {ax, ay} = Enum.at(pts, rem(i - 1 + n, n))
      {hx, hy} = Enum.at(pts, i)
      {bx, by} = Enum.at(pts, rem(i + 1, n))
      a = :math.atan2(hy - ay, hx - ax)
      b = :math.atan2(by - hy, bx - hx)
      abs(TartarusArena.Geometry.wrap_angle(b - a)) * 180 / :math.pi()
    end
    |> Enum.max()
  end

  @tag :tmp_dir
  test "the experiment at a small size: every condition ranked beside Table 6.5, files written",
       %{tmp_dir: dir} do
    {:ok, %{summary: s, files: files}} =
      Sensitivity.run(seeds: 1, seed: 7, pfas: ~w(A1 A2), out: dir, quiet: true)

    assert Map.keys(s.conditions) |> Enum.sort() ==
             Enum.sort(~w(kinematic footprint inertia rounded all))

    for {_, c} <- s.conditions do
      assert Map.keys(c.best) == Paths.types()
      assert Enum.all?(c.best, fn {_, pfa} -> pfa in ~w(A1 A2) end)
      assert c.matches == Enum.count(c.best, fn {t, p} -> Sensitivity.table6_5()[t] == p end)
    end

    assert s.supported["rounded"] ==
             (s.conditions["rounded"].best[:sp_b] == "A2" or
                s.conditions["rounded"].best[:sp_d] == "A2")

    assert Enum.any?(files, &String.ends_with?(&1, "ranking.svg"))
    # a row per sub-path run: 5 conditions x 2 PFAs x 9 instances
    rows = File.read!(Path.join(dir, "runs.csv")) |> String.split("\n", trim: true)
    assert length(rows) == 1 + 5 * 2 * 9
    md = File.read!(Path.join(dir, "summary.md"))
    assert md =~ "| Table 6.5 |" and md =~ "## Provenance"
  end

  @tag :tmp_dir
  test "mix tartarus.arena --experiment sensitivity: --help, a bad --pfas, --json", %{
    tmp_dir: dir
  } do
    Mix.shell(Mix.Shell.Process)
    on_exit(fn -> Mix.shell(Mix.Shell.IO) end)
    Mix.Tasks.Tartarus.Arena.run(["--help"])
    assert_received {:mix_shell, :info, [text]}
    assert text =~ "--experiment sensitivity" and text =~ "table6_5_reproduced"

    assert_raise Mix.Error, ~r/--pfas/, fn ->
      Mix.Tasks.Tartarus.Arena.run(~w(--experiment sensitivity --pfas A9))
    end

    Mix.Tasks.Tartarus.Arena.run(
      ~w(--experiment sensitivity --seeds 1 --seed 7 --pfas A4 --json --out) ++ [dir]
    )

    assert_received {:mix_shell, :info, [json]}
    {:ok, s} = Tartarus.JSON.decode(json)
    assert s["experiment"] == "sensitivity" and s["pfas"] == ["A4"]
    assert s["conditions"]["all"]["best"]["sp_b"] == "A4"
    assert s["provenance"]["argv"] != nil
  end
end
