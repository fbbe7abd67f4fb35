defmodule TartarusWarehouse.FloorBurstTest do
  # Bursts of submissions (issue 44, item 5): the distributor holds at most
  # `max_pending_tasks` tasks of jobs accepted and not completed; a job beyond is answered
  # {:error, :queue_full} at once, and every job answered :ok completes, with the
  # distributor's failover or without.
  # Before: 8,000 jobs submitted at once to 3 robots got the distributor killed by its
  # 64 MiB heap limit after it accepted 5,741; the accepted jobs were lost and every later
  # submission refused.
  use ExUnit.Case, async: false

  alias Tartarus.Clock
  alias TartarusWarehouse.Floor

  # A three-task job: pick, carry, pack, one after the other, each on its own resource.
  defp job(id) do
    tasks =
      for {name, resource, after_tasks} <- [
            {"pick", :rack, []},
            {"carry", :aisle, ["pick"]},
            {"pack", :packing, ["carry"]}
          ],
          do: %{name: name, resources: [resource], after: after_tasks}

    %{id: id, tasks: tasks}
  end

  # `n` jobs submitted at once (one process each) to a floor started with `opts`, in
  # virtual time (`Tartarus.Clock.Virtual`: no time passes while the submissions are
  # handled, so the figures are the design's); `during` runs on the floor while they are
  # submitted. Returns each job's answer, the floor's result and its status at the end.
  defp burst(n, opts, during \\ fn _f -> :ok end) do
    Clock.Virtual.run([seed: 1], fn ->
      {:ok, f} =
        Floor.start(Keyword.merge([robots: 3, resources: [:rack, :aisle, :packing]], opts))

      submits =
        Task.async_stream(1..n, &{&1, Floor.submit(f, job(&1))},
          max_concurrency: n,
          timeout: :infinity
        )

      during = Task.async(fn -> during.(f) end)
      answers = Map.new(submits, fn {:ok, answer} -> answer end)
      Task.await(during, :infinity)
      awaited = Floor.await(f, 3_600_000)
      st = Floor.status(f)
      {:ok, r} = Floor.stop(f)
      {answers, awaited, r, st}
    end)
  end

  defp census(answers, awaited, r, st) do
    accepted = for {id, :ok} <- answers, do: id
    refused = for {id, {:error, :queue_full}} <- answers, do: id

    # each job either accepted or refused for a full queue, nothing else
    assert length(accepted) + length(refused) == map_size(answers)
    # 0 accepted and lost
    assert awaited == :ok and st.failed == nil and r.failed == nil
    assert Enum.sort(Map.keys(r.completed)) == Enum.sort(accepted)
    assert r.timed_out == [] and r.mutex_violations == 0
    {accepted, refused}
  end

  test "200 jobs at once on a bound of 60 tasks: the rest refused with :queue_full, every accepted job completes" do
    {answers, awaited, r, st} = burst(200, max_pending_tasks: 60, scale: 0.005)
    {accepted, refused} = census(answers, awaited, r, st)
    # in virtual time no job completes while the burst is handled: exactly the bound
    assert length(accepted) == 20 and length(refused) == 180

    # room again once jobs completed
    {:ok, f} = Floor.start(robots: 2, resources: [:rack, :aisle, :packing], max_pending_tasks: 3)
    assert :ok = Floor.submit(f, job(1))
    assert {:error, :queue_full} = Floor.submit(f, job(2))
    assert :ok = Floor.await(f, 30_000)

    # a job that would never fit
    assert {:error,
            "job 3 has 4 tasks, more than the distributor holds at once (max_pending_tasks: 3)"} =
             Floor.submit(f, %{job(3) | tasks: [%{name: "x", resources: [:rack]} | job(3).tasks]})

    assert :ok = Floor.submit(f, job(2))
    assert :ok = Floor.await(f, 30_000)
    {:ok, _} = Floor.stop(f)
  end

  test "a burst with the distributor's host killed during it (failover): every accepted job completes" do
    kill = fn f -> assert :ok = Floor.change(f, {:kill_distributor, 20}) end

    {answers, awaited, r, st} =
      burst(200, [max_pending_tasks: 60, scale: 0.005, failover: true], kill)

    {accepted, _refused} = census(answers, awaited, r, st)
    assert length(accepted) >= 20
    assert [_] = r.killed_at_us
  end

  test "run/1's jobs beyond the bound wait in the floor and all run" do
    {:ok, r} =
      Floor.run(robots: 3, jobs: Enum.map(1..60, &job/1), max_pending_tasks: 15, scale: 0.005)

    assert r.timed_out == [] and map_size(r.completed) == 60 and r.failed == nil

    assert {:error,
            "invalid options given to TartarusWarehouse.Floor for key :jobs: job 1 has more tasks than max_pending_tasks (2): the distributor would never take it"} =
             Floor.run(robots: 3, jobs: [job(1)], max_pending_tasks: 2)
  end

  # About 30 s of wall time (3,333 jobs run, in virtual time): a longer test.
  @tag :long
  @tag timeout: 600_000
  test "8,000 three-task jobs at once on 3 robots: each completed or refused at submission, none accepted and lost" do
    {answers, awaited, r, st} = burst(8_000, scale: 0.005)
    {accepted, refused} = census(answers, awaited, r, st)
    # the default bound, max_pending_tasks 10,000: 3,333 jobs of 3 tasks
    assert length(accepted) == 3_333 and length(refused) == 4_667
  end
end
