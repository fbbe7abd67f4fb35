defmodule TartarusWarehouse.DistributorTest do
  use ExUnit.Case, async: true
  doctest TartarusWarehouse.Distributor
  doctest TartarusWarehouse.Checker

  alias TartarusWarehouse.{Distributor, Job}

  @world Job.world([:a, :b, :c, :d], 2)

  defp seq(id, rs),
    do: %{
      id: id,
      tasks:
        rs
        |> Enum.with_index()
        |> Enum.map(fn {r, i} ->
          %{name: "T#{i}", resources: [r], after: if(i > 0, do: ["T#{i - 1}"], else: [])}
        end)
    }

  test "a malformed job changes nothing" do
    d = Distributor.new(@world)
    assert {:error, _} = Distributor.submit(d, %{id: 1, tasks: []})
    {:ok, d1, _} = Distributor.submit(d, seq(1, [:a]))
    assert {:error, "job id 1 is already in use"} = Distributor.submit(d1, seq(1, [:b]))
  end

  test "a later job waits for the resources an earlier job's agents hold, and reuses its agents" do
    d = Distributor.new(@world)
    {:ok, d, a1} = Distributor.submit(d, seq(1, [:a, :b]))
    assert [{:release, 1, _}, {:release, 2, _}] = a1
    {:ok, d, []} = Distributor.submit(d, seq(2, [:a, :b]))
    assert Distributor.held(d) == %{a: 1, b: 2}
    {d, []} = Distributor.started(d, 1)
    {d, [{:reissue, 1, %{job: 2, index: 0}}]} = Distributor.done(d, 1)
    {d, []} = Distributor.started(d, 1)
    {d, [{:job_done, 1}, {:reissue, 2, %{job: 2, index: 1}}]} = Distributor.done(d, 2)
    {d, [{:retire, 1}]} = Distributor.done(d, 1)
    {d, [{:job_done, 2}, {:retire, 2}]} = Distributor.done(d, 2)
    assert Distributor.held(d) == %{}
    assert Distributor.pending_jobs(d) == []
  end

  test "no overtaking: jobs get a resource in the order they arrived (first come, first served)" do
    d = Distributor.new(@world)
    {:ok, d, _} = Distributor.submit(d, seq(1, [:a]))
    {d, []} = Distributor.started(d, 1)
    # Job 2's second block (:b) goes at once; its first block waits for :a.
    {:ok, d, [{:release, 2, %{job: 2, index: 1}}]} = Distributor.submit(d, seq(2, [:a, :b]))
    {:ok, d, []} = Distributor.submit(d, seq(3, [:a]))
    # When :a comes back it goes to job 2, not job 3.
    {d, [{:job_done, 1}, {:reissue, 1, %{job: 2, index: 0}}]} = Distributor.done(d, 1)
    {d, []} = Distributor.started(d, 1)
    {_d, [{:reissue, 1, %{job: 3}}]} = Distributor.done(d, 1)
    # Independent resources go at once.
    {:ok, _d, [{:release, _, %{job: 4}}]} =
      Distributor.submit(
        Distributor.new(@world)
        |> then(fn d -> elem(Distributor.submit(d, seq(1, [:a])), 1) end)
        |> then(&elem(Distributor.started(&1, 1), 0)),
        seq(4, [:c])
      )
  end

  test "a first block goes only once the previous first block booked a robot" do
    d = Distributor.new(@world)
    {:ok, d, [{:release, 1, _}]} = Distributor.submit(d, seq(1, [:a]))
    {:ok, d, []} = Distributor.submit(d, seq(2, [:b]))
    {_d, [{:release, 2, %{job: 2}}]} = Distributor.started(d, 1)
  end

  test "resources held by live agents are disjoint at every step of a random schedule" do
    rng = :rand.seed_s(:exsss, 42)

    {d, out, _rng} =
      Enum.reduce(1..30, {Distributor.new(@world), [], rng}, fn j, {d, out, rng} ->
        {n, rng} = :rand.uniform_s(3, rng)
        {rs, rng} = Enum.map_reduce(1..n, rng, fn _, rng -> :rand.uniform_s(4, rng) end)

        {:ok, d, actions} =
          Distributor.submit(d, seq(j, Enum.map(rs, &Enum.at([:a, :b, :c, :d], &1 - 1))))

        drain(d, out ++ refs(actions), rng)
      end)

    {d, [], _} = drain(d, out, rng, :all)
    assert Distributor.pending_jobs(d) == []
  end

  defp refs(actions), do: for({kind, ref, _} <- actions, kind in [:release, :reissue], do: ref)

  # Finish agents at random (starting first blocks first), checking the invariant.
  defp drain(d, out, rng, mode \\ :some)
  defp drain(d, [], rng, _mode), do: {d, [], rng}

  defp drain(d, out, rng, mode) do
    # The agents out hold disjoint resources (each resource has one token).
    rs = d.out |> Map.values() |> Enum.flat_map(& &1.resources)
    assert length(rs) == length(Enum.uniq(rs))
    {i, rng} = :rand.uniform_s(length(out), rng)
    ref = Enum.at(out, i - 1)
    {d, a1} = Distributor.started(d, ref)
    {d, a2} = Distributor.done(d, ref)
    out = List.delete(out, ref) ++ refs(a1 ++ a2)
    {stop, rng} = :rand.uniform_s(3, rng)
    if mode == :some and stop == 1, do: {d, out, rng}, else: drain(d, out, rng, mode)
  end
end
