defmodule TartarusArena.PathsTest do
  use ExUnit.Case, async: true

  alias TartarusArena.{PFAs, Paths, PFA, Run, World}

  test "both paths close, are made of the thesis's sub-path types, and carry jittered Table 6.3 features" do
    p1 = Paths.path(1, 3)
    p2 = Paths.path(2, 3)
    assert Enum.map(p1.subpaths, & &1.type) == [:sp_c, :sp_a, :sp_b, :sp_a]
    assert Enum.map(p2.subpaths, & &1.type) == [:sp_c, :sp_a, :sp_d, :sp_b, :sp_a]

    for p <- [p1, p2], sp <- p.subpaths do
      table = Paths.table_features(sp.type)
      assert length(sp.features) == 4
      assert Enum.all?(Enum.zip(sp.features, table), fn {f, t} -> abs(f - t) <= 0.05 + 1.0e-9 end)
      assert sp.to > sp.from
    end

    assert List.last(p1.subpaths).to == p1.length
    # instances of one type differ
    [_, a1, _, a2] = p1.subpaths
    refute a1.features == a2.features
    assert Paths.path(1, 3) == p1
    refute Paths.path(1, 4).subpaths == p1.subpaths
  end

  test "lap detection: a full circuit is one lap; dithering around the flag is none" do
    p = Paths.path(1, 0)
    {x0, y0, _} = p.start
    tr = Paths.track_new(p, x0, y0)

    # back and forth across the flag
    {tr, laps} =
      Enum.reduce([0.05, -0.05, 0.04, -0.03, 0.02], {tr, 0}, fn s, {tr, n} ->
        {x, y, _} = Paths.point_at(p, s)
        {tr, lap?} = Paths.track(tr, p, x, y)
        {tr, n + if(lap?, do: 1, else: 0)}
      end)

    assert laps == 0

    {tr, laps} =
      Enum.reduce(1..(round(p.length / 0.02) + 5), {tr, []}, fn k, {tr, laps} ->
        {x, y, _} = Paths.point_at(p, 0.02 + k * 0.02)
        {tr, lap?} = Paths.track(tr, p, x, y)
        {tr, if(lap?, do: [k | laps], else: laps)}
      end)

    assert length(laps) == 1
    assert tr.laps == 1
  end

  test "progress: a cut corner is caught up once the robot is back on the line (no lag); " <>
         "a shortcut is not, and is flagged" do
    p = Paths.path(2, 1)
    sp = Enum.find(p.subpaths, &(&1.type == :sp_d))
    at = fn s -> Paths.point_at(p, sp.from + s) end
    {x0, y0, _} = at.(0.0)
    tr0 = Paths.track_new(p, x0, y0)

    # along the first leg to 0.2 m before the corner (0.3 m), then off the line 6 cm to the
    # side, then back on the line 0.1 m after the corner: 0.2 m of line for ~0.1 m moved
    tr =
      Enum.reduce(1..5, tr0, fn k, tr ->
        elem(Paths.track(tr, p, elem(at.(k * 0.02), 0), elem(at.(k * 0.02), 1)), 0)
      end)

    {xm, ym, _} = at.(0.3)
    {tr, _} = Paths.track(tr, p, xm - 0.06, ym + 0.06)
    assert tr.distance > 0.05
    {xb, yb, _} = at.(0.4)
    {tr, _} = Paths.track(tr, p, xb, yb)
    refute tr.skipped
    assert_in_delta tr.progress, 0.4, 1.0e-6

    # following the line from there on keeps it so, over a whole lap
    steps = round(p.length / 0.02)

    {tr, laps} =
      Enum.reduce(1..steps, {tr, 0}, fn k, {tr, n} ->
        {x, y, _} = at.(0.4 + k * 0.02)
        {tr, lap?} = Paths.track(tr, p, x, y)
        {tr, n + if(lap?, do: 1, else: 0)}
      end)

    assert_in_delta tr.progress, 0.4 + steps * 0.02, 1.0e-6
    assert laps == 1

    # a jump from the start to the line 0.6 m further on is a shortcut: progress stays
    # within what the robot moved, and the robot is put back there
    {xa, ya, _} = at.(0.6)
    {tr, _} = Paths.track(tr0, p, (x0 + xa) / 2 + 0.15, (y0 + ya) / 2 + 0.15)
    {tr, _} = Paths.track(tr, p, xa, ya)
    assert tr.skipped and tr.progress < 0.6 - 0.15
    {tr, {x, y, _}} = Paths.back_to_progress(tr, p)
    refute tr.skipped
    assert_in_delta tr.along, tr.progress, 1.0e-9
    {tr2, _} = Paths.track(tr, p, x, y)
    refute tr2.skipped
    assert_in_delta tr2.progress, tr.progress, 1.0e-6
  end

  for pfa <- PFAs.all() do
    test "#{inspect(pfa)} keeps a robot on a straight and on a curved line" do
      p = Paths.path(1, 0)

      for index <- [0, 1] do
        r = Run.subpath(unquote(pfa), p, index, seed: 11)
        assert r.completed, "#{inspect(unquote(pfa))} on #{r.type}: #{inspect(r)}"
        assert r.on_line >= 0.95, "#{inspect(unquote(pfa))} on #{r.type}: #{inspect(r)}"
        assert r.features == Enum.at(p.subpaths, index).features
      end
    end
  end

  test "laps: a robot with A4 laps path 1, timed, with its sub-paths measured; deterministic" do
    p = Paths.path(1, 0)

    go = fn ->
      Run.laps([%{robot: :r, path: p, choose: PFA.A4}], Run.arena([{:r, p, 0.0}], seed: 5),
        laps: 2
      )
    end

    res = go.()
    %{lap_times: [t1, t2], subpaths: subs, lost: 0} = res.robots.r
    assert t1 > 20 and t1 < 40 and t2 > 20 and t2 < 40
    assert Enum.map(Enum.take(subs, 4), & &1.type) == [:sp_c, :sp_a, :sp_b, :sp_a]
    assert_in_delta Enum.sum(Enum.map(Enum.take(subs, 4), & &1.time)), t1, 0.05
    assert go.() == res
    assert World.time(res.world) == res.time
  end

  test "laps: a chooser picks a PFA per sub-path; a lost robot is put back and charged" do
    p = Paths.path(2, 0)
    choose = fn sp -> if sp.type == :sp_c, do: PFA.A1, else: PFA.A7 end

    res =
      Run.laps([%{robot: :r, path: p, choose: choose}], Run.arena([{:r, p, 0.0}], seed: 5),
        laps: 1
      )

    subs = res.robots.r.subpaths
    assert Enum.map(subs, & &1.pfa) == ["A1", "A7", "A7", "A7", "A7"]
    assert length(res.robots.r.lap_times) == 1
  end

  test "laps: a policy chooses every sub-path's PFA and hears every result and lap, in order" do
    p1 = Paths.path(1, 0)
    p2 = Paths.path(2, 0)
    pfas = PFAs.all()

    policy = fn
      {:choose, robot, sp}, st ->
        pfa = Enum.at(pfas, rem(length(st.chosen), 8))
        {pfa, %{st | chosen: [{robot, sp.index, PFAs.name(pfa)} | st.chosen]}}

      {:result, robot, r}, st ->
        %{st | results: [{robot, r.index, r.pfa} | st.results]}

      {:lap, robot, n, secs}, st ->
        %{st | laps: [{robot, n, secs} | st.laps]}
    end

    res =
      Run.laps(
        [%{robot: :a, path: p1}, %{robot: :b, path: p2}],
        Run.arena([{:a, p1, 0.0}, {:b, p2, 0.0}], seed: 2),
        laps: 1,
        policy: policy,
        policy_state: %{chosen: [], results: [], laps: []}
      )

    st = res.policy_state

    for robot <- [:a, :b] do
      subs = res.robots[robot].subpaths
      results = for {^robot, i, pfa} <- Enum.reverse(st.results), do: {i, pfa}
      assert results == Enum.map(subs, &{&1.index, &1.pfa})
      chosen = for {^robot, i, pfa} <- Enum.reverse(st.chosen), do: {i, pfa}
      # every sub-path crossed was chosen first; the last choice is the next lap's first
      assert Enum.take(chosen, length(results)) == results
      assert [{^robot, 1, secs}] = Enum.filter(st.laps, &(elem(&1, 0) == robot))
      assert res.robots[robot].lap_times == [secs]
    end

    # the choices rotate through the eight PFAs across both robots
    assert st.chosen |> Enum.map(&elem(&1, 2)) |> Enum.uniq() |> length() == 8
  end

  defmodule Straight do
    @moduledoc false
    @behaviour TartarusArena.PFA
    def init(_), do: nil
    def control(_, _, s), do: {{1.0, 1.0}, s}
    def strategy, do: "straight ahead, whatever the line"
  end

  test "laps: a robot that leaves the line is put back on it and charged the penalty" do
    p = Paths.path(1, 0)

    res =
      Run.laps([%{robot: :r, path: p, choose: Straight}], Run.arena([{:r, p, 0.0}], seed: 5),
        laps: 1,
        max_time: 20.0
      )

    assert res.robots.r.lost >= 1
    assert res.robots.r.lap_times == []
    {x, y, _} = World.pose(res.world, :r)
    {_, d, _} = Paths.locate(p, x, y)
    assert d <= 0.25
  end
end
