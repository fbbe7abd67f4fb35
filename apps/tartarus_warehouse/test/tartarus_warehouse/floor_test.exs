defmodule TartarusWarehouse.FloorTest do
  use ExUnit.Case, async: false
  doctest TartarusWarehouse.Floor
  doctest TartarusWarehouse.Floor.Build
  doctest TartarusWarehouse.Floor.Options

  import Tartarus.TestSupport

  alias TartarusWarehouse.{Checker, Floor}
  alias TartarusWarehouse.Experiment.Jobs
  alias TartarusTools.Prop

  test "task agents run 6 jobs on 3 robots: every job completes, no resource is held twice, robots pipeline" do
    jobs = Jobs.thesis_jobs(6, 1000)
    {:ok, r} = Floor.run(robots: 3, jobs: jobs, scale: 0.01, jitter: 0.3, seed: 3)
    assert r.timed_out == []
    assert Checker.violations(r.history) == []
    c = Checker.completion(r.history, jobs)
    assert Enum.sort(c.completed) == Enum.to_list(1..6)
    assert length(r.history) == 24
    # More than one robot worked, and some instant had two executing at once.
    assert r.history |> Enum.map(& &1.robot) |> Enum.uniq() |> length() > 1

    assert Enum.any?(Checker.occupancy(r.history, r.t0_us, 5).series, fn {_, busy} -> busy > 1 end)

    assert r.migrations > 0
  end

  test "jobs arrive asynchronously: a job submitted later starts later and still completes" do
    jobs = Jobs.thesis_jobs(3, 1000)
    {:ok, r} = Floor.run(robots: 2, jobs: jobs, scale: 0.01, arrivals_ms: [0, 0, 120])
    assert r.timed_out == []
    assert length(Checker.completion(r.history, jobs).completed) == 3
    first_of_3 = r.history |> Enum.filter(&(&1.job == 3)) |> Enum.map(& &1.start_us) |> Enum.min()
    assert first_of_3 - r.t0_us >= 120_000
  end

  test "run/1 drives the floor's one process: the batch's events are its changes, and the floor goes with its caller" do
    jobs = Jobs.thesis_jobs(3, 1000)

    {:ok, r} =
      Floor.run(
        robots: 1,
        jobs: jobs,
        scale: 0.01,
        events: [{1, {:retire, 1}}, {2, {:delete, "T4"}}]
      )

    assert r.timed_out == [] and r.failed == nil and r.mutex_violations == 0

    assert [
             %{event: {:retire, 1}, result: {:error, last}},
             %{event: {:delete, "T4"}, result: :ok}
           ] = r.changes

    assert last =~ "robot 1 is the last robot in service"
    assert [%{event: {:delete, "T4"}}] = r.applied_events
    assert [%{event: {:retire, 1}, reason: ^last}] = r.refused_events

    # The caller of run/1 dies while its jobs run: the floor stops and its hosts go.
    hosts_before = length(Tartarus.hosts())
    long = [%{id: 1, tasks: [%{name: "T1", resources: [:a], duration_ms: 400_000}]}]
    caller = spawn(fn -> Floor.run(robots: 2, jobs: long, scale: 0.01) end)
    eventually(fn -> floors() != [] end)
    [floor] = floors()
    ref = Process.monitor(floor)
    Process.exit(caller, :kill)
    assert_receive {:DOWN, ^ref, :process, ^floor, _}, 10_000
    eventually(fn -> length(Tartarus.hosts()) == hosts_before end)
  end

  # The floors running now (GenServers of this module).
  defp floors do
    # A process may end between the list and the look (then it is no floor of ours).
    for pid <- Process.list(),
        {:dictionary, dict} <- [Process.info(pid, :dictionary)],
        match?({Floor, :init, 1}, Keyword.get(dict, :"$initial_call")),
        do: pid
  end

  test "the centralized baseline runs the same jobs with no migration" do
    jobs = Jobs.thesis_jobs(4, 1000)
    {:ok, r} = Floor.run(robots: 2, jobs: jobs, scale: 0.01, design: :central)
    assert r.timed_out == []
    assert Checker.violations(r.history) == []
    assert length(Checker.completion(r.history, jobs).completed) == 4
    assert r.migrations == 0
  end

  test "a central server with a service time makes every robot wait for it between blocks" do
    # One robot: each block starts only after the server handled the previous "finished"
    # (service_ms) and sent the next command. A lower bound only: no timing upper bound.
    jobs = Jobs.thesis_jobs(2, 1000)
    {:ok, r} = Floor.run(robots: 1, jobs: jobs, scale: 0.01, design: :central, service_ms: 25)
    assert r.timed_out == []
    assert length(Checker.completion(r.history, jobs).completed) == 2
    runs = Enum.sort_by(r.history, & &1.start_us)
    gaps = for [a, b] <- Enum.chunk_every(runs, 2, 1, :discard), do: b.start_us - a.stop_us
    assert length(gaps) == 7
    assert Enum.all?(gaps, &(&1 >= 25_000))
  end

  test "the central server handles 3 messages a task and each job; the distributor one a block, one a job" do
    jobs = Jobs.soft_jobs(3, 4, 2000)

    {:ok, c} = Floor.run(robots: 4, jobs: jobs, scale: 0.005, design: :central, service_ms: 0.5)

    {:ok, a} = Floor.run(robots: 4, jobs: jobs, scale: 0.005, service_ms: 0.5)

    for r <- [c, a] do
      assert r.timed_out == [] and r.mutex_violations == 0
      assert length(r.history) == 12
    end

    # central: 3 submissions + 12 tasks x (started, finished, the command)
    assert length(c.service_log) == 3 + 12 * 3
    # agents: 3 submissions + 12 done + 3 started (a job's first block)
    assert length(a.service_log) == 3 + 12 + 3
    # one server: no two messages in service at once, each took its 0.5 ms
    for r <- [c, a] do
      served = r.service_log |> Enum.sort_by(&elem(&1, 1))

      assert Enum.all?(served, fn {arrived, start, done} ->
               start >= arrived and done - start == 500
             end)

      assert served
             |> Enum.chunk_every(2, 1, :discard)
             |> Enum.all?(fn [{_, _, d1}, {_, s2, _}] -> s2 >= d1 end)
    end
  end

  test "agents that continue serve the next jobs without returning: same tasks, fewer messages to the distributor" do
    jobs = Jobs.soft_jobs(8, 3, 2000)

    for guide <- [false, true] do
      {:ok, back} =
        Floor.run(
          robots: 4,
          jobs: jobs,
          scale: 0.005,
          guide: guide,
          secondary: 2,
          phi: 2,
          service_ms: 0.2
        )

      {:ok, on} =
        Floor.run(
          robots: 4,
          jobs: jobs,
          scale: 0.005,
          guide: guide,
          continue: true,
          secondary: 2,
          phi: 2,
          service_ms: 0.2
        )

      for r <- [back, on] do
        assert r.timed_out == [] and r.mutex_violations == 0
        assert length(Checker.completion(r.history, jobs).completed) == 8
      end

      assert length(on.service_log) < length(back.service_log)
    end
  end

  test "independent sequences run on different robots; a robot retired after job 1 takes no more work" do
    job = fn id ->
      %{
        id: id,
        tasks: [
          %{name: "Fetch", resources: [:rack], duration_ms: 1000},
          %{name: "Carry", resources: [:path], after: ["Fetch"], duration_ms: 1000},
          %{name: "Stamp", resources: [:stamp], duration_ms: 1000},
          %{name: "Place", resources: [:shelf], after: ["Stamp"], duration_ms: 1000}
        ]
      }
    end

    jobs = Enum.map(1..4, job)
    {:ok, r} = Floor.run(robots: 3, jobs: jobs, scale: 0.01, retire: [{3, 1}])
    assert r.timed_out == []
    assert Checker.violations(r.history) == []
    assert length(Checker.completion(r.history, jobs).completed) == 4
    c = Checker.completion(r.history, jobs)
    assert c.split == []

    # Some job's two sequences ran at the same time on two robots.
    assert Enum.any?(1..4, fn j ->
             case r.history
                  |> Enum.filter(&(&1.job == j))
                  |> Enum.group_by(& &1.seq)
                  |> Map.values() do
               [a, b] ->
                 hd(a).robot != hd(b).robot and
                   Enum.min_by(a, & &1.start_us).start_us < Enum.max_by(b, & &1.stop_us).stop_us and
                   Enum.min_by(b, & &1.start_us).start_us < Enum.max_by(a, & &1.stop_us).stop_us

               _ ->
                 false
             end
           end)

    # r3 is retired once the first job completed (the event takes effect a moment later):
    # after that it only finished what it had begun (a block claimed before may start
    # after: what counts is when the robot was claimed for it).
    [retired_at] = for %{event: {:retire, 3}, at_us: at} <- r.applied_events, do: at

    begun =
      for e <- r.history,
          e.robot == "r3",
          e.claimed_us < retired_at,
          into: MapSet.new(),
          do: {e.job, e.seq}

    assert Enum.all?(
             r.history,
             &(&1.robot != "r3" or &1.claimed_us < retired_at or {&1.job, &1.seq} in begun)
           )
  end

  test "on-the-fly programming: a task added with a program compiled at run time runs in later jobs, a deleted task is skipped" do
    {:ok, [detour]} =
      Tartarus.compile_string("""
      defmodule TartarusWarehouse.FloorTest.Detour do
        use TartarusWarehouse.Program
        def work(data), do: Enum.reverse(data)
      end
      """)

    jobs = Jobs.thesis_jobs(6, 1000)
    t2a = %{name: "T2A", resources: [:detour], program: detour, duration_ms: 1000}

    {:ok, r} =
      Floor.run(
        robots: 2,
        jobs: jobs,
        scale: 0.01,
        resources: [:bay, :line, :rack, :wall, :packing, :return, :detour],
        events: [{0, {:insert, "T2", t2a}}, {3, {:delete, "T4"}}]
      )

    assert r.timed_out == []
    assert Checker.violations(r.history) == []
    assert length(Checker.completion(r.history, jobs).completed) == 6

    # Inserted right after submission: every job but (perhaps) the first runs T2A, after T2 and before T3.
    with_t2a = for e <- r.history, e.task == "T2A", do: e.job
    assert Enum.sort(with_t2a) -- [1] == [2, 3, 4, 5, 6]

    for j <- with_t2a do
      at = Map.new(for e <- r.history, e.job == j, do: {e.task, e})
      assert at["T2"].stop_us <= at["T2A"].start_us and at["T2A"].stop_us <= at["T3"].start_us
      assert at["T2A"].robot == at["T2"].robot
    end

    # T4 was deleted once 3 jobs completed: the last job skipped it (holding nothing).
    assert [%{skipped: true, resources: []}] =
             for(e <- r.history, e.job == 6, e.task == "T4", do: e)
  end

  test "a standby robot joins while the floor runs" do
    jobs = Jobs.thesis_jobs(6, 1000)

    {:ok, r} =
      Floor.run(robots: 2, standby: [2], jobs: jobs, scale: 0.01, events: [{2, {:join, 2}}])

    assert r.timed_out == []
    assert Checker.violations(r.history) == []
    first_r2 = r.history |> Enum.filter(&(&1.robot == "r2")) |> Enum.map(& &1.job) |> Enum.min()
    assert first_r2 > 2
  end

  test "the distributor's host killed twice and started again on its journal: no job lost, none duplicated" do
    jobs = Jobs.thesis_jobs(8, 1000)

    {:ok, r} =
      Floor.run(
        robots: 3,
        jobs: jobs,
        scale: 0.01,
        failover: true,
        events: [{{:ms, 5}, {:kill_distributor, 60}}, {{:ms, 110}, {:kill_distributor, 30}}]
      )

    assert length(r.killed_at_us) == 2
    assert r.timed_out == []
    assert Checker.violations(r.history) == []
    c = Checker.completion(r.history, jobs)
    assert c.duplicated == [] and c.missing == []
    assert length(c.completed) == 8

    # Without persistence the same loss stops every job that was not done.
    {:ok, lost} =
      Floor.run(
        robots: 3,
        jobs: jobs,
        scale: 0.01,
        timeout_ms: 1_000,
        events: [{{:ms, 5}, {:kill_distributor, 60}}]
      )

    assert lost.timed_out != []
  end

  test "a task inserted and deleted at once: every robot applies the two changes in order, no robot waits for the deleted task" do
    # Found by the property below: the two sequence agents travel concurrently, and a robot
    # that got the deletion before the insertion kept the insertion and, after job 4's
    # block (which ends with T2), waited forever for the deleted task's agent; job 5 never
    # ran (8 runs in 10 of this case hung).
    task = fn name, after_task ->
      %{name: name, resources: [:a, :b], duration_ms: 1000, after: after_task}
    end

    four = [task.("T1", []), task.("T2", ["T1"]), task.("T3", []), task.("T4", ["T3"])]

    jobs =
      [four, four, four, [task.("T1", []), task.("T2", [])], [task.("T1", [])]]
      |> Enum.with_index(1)
      |> Enum.map(fn {tasks, id} -> %{id: id, tasks: tasks} end)

    x = %{name: "X", resources: [:x], duration_ms: 700}

    for seed <- 51..58 do
      {:ok, r} =
        Floor.run(
          robots: 2,
          jobs: jobs,
          resources: [:a, :b, :x],
          scale: 0.005,
          seed: seed,
          retire: [{2, 1}],
          events: [{0, {:insert, "T2", x}}, {0, {:delete, "X"}}, {2, {:delete, "T2"}}],
          timeout_ms: 5_000
        )

      assert r.timed_out == [], "seed #{seed}: jobs #{inspect(r.timed_out)} never completed"
      assert Checker.violations(r.history) == []
    end
  end

  test "a floor you drive: jobs submitted over time, a task inserted, a robot joining and one retiring, then stopped" do
    hosts_before = length(Tartarus.hosts())

    job = fn id ->
      %{
        id: id,
        tasks: [
          %{name: "T1", resources: [:rack]},
          %{name: "T2", resources: [:bay], after: ["T1"]}
        ]
      }
    end

    {:ok, f} =
      Floor.start(robots: 3, standby: [3], resources: [:rack, :bay, :detour], scale: 0.005)

    assert :ok = Floor.submit(f, job.(1))
    assert {:error, "job 1 was already submitted"} = Floor.submit(f, job.(1))
    assert {:error, _} = Floor.submit(f, %{id: 9, tasks: []})

    assert :ok =
             Floor.change(
               f,
               {:insert, "T1", %{name: "X", resources: [:detour], duration_ms: 600}}
             )

    assert {:error, _} = Floor.change(f, {:retire, 7})
    assert :ok = Floor.change(f, {:join, 3})
    for id <- 2..6, do: assert(:ok = Floor.submit(f, job.(id)))

    st = Floor.status(f)
    assert st.jobs == [1, 2, 3, 4, 5, 6]
    assert Enum.sort(st.done ++ st.pending) == [1, 2, 3, 4, 5, 6]
    assert %{state: _, off: false} = st.robots["r3"]

    assert :ok = Floor.await(f, 20_000)
    assert :ok = Floor.change(f, {:retire, 1})
    assert :ok = Floor.submit(f, job.(7))
    assert :ok = Floor.await(f, 20_000)

    {:ok, r} = Floor.stop(f)
    eventually(fn -> not Process.alive?(f) end)
    assert r.jobs == [1, 2, 3, 4, 5, 6, 7] and r.timed_out == [] and r.mutex_violations == 0
    # job 7 ran after robot 1 left; X ran after T1 from the insertion on
    assert Enum.all?(r.history, &(not (&1.job == 7 and &1.robot == "r1")))
    assert Enum.any?(r.history, &(&1.task == "X"))
    assert Enum.map(r.changes, & &1.result) == [:ok, {:error, "no robot 7"}, :ok, :ok]
    eventually(fn -> length(Tartarus.hosts()) == hosts_before end)
  end

  test "a floor you drive: bad options and a dashboard that cannot start are errors, and nothing is left running" do
    hosts_before = length(Tartarus.hosts())

    assert {:error, "invalid options given to TartarusWarehouse.Floor.start/1" <> _} =
             Floor.start(robots: 0)

    assert {:error, message} =
             Floor.start(robots: 2, resources: [:a], dashboard: [port: 0, token: "short"])

    assert message =~ "token"
    eventually(fn -> length(Tartarus.hosts()) == hosts_before end)

    # With a dashboard: its warehouse panel shows the floor, and goes with it.
    {:ok, l} = :gen_tcp.listen(0, [])
    {:ok, port} = :inet.port(l)
    :gen_tcp.close(l)

    {:ok, f} =
      Floor.start(robots: 2, resources: [:a], dashboard: [port: port, token: "floor-test-token"])

    url = "http://127.0.0.1:#{port}/api/panels"
    {:ok, 200, body} = TartarusDashboard.http_get(url, 5_000)

    assert [%{"name" => "warehouse", "rows" => [["r1" | _], ["r2" | _]]} = panel] =
             Tartarus.JSON.decode!(body)["panels"]

    assert panel["text"] =~ "on 2 robots: 0 of 0 jobs done"
    {:ok, _} = Floor.stop(f)
    assert {:error, _} = TartarusDashboard.http_get(url, 2_000)
    eventually(fn -> length(Tartarus.hosts()) == hosts_before end)
  end

  test "a floor you drive: its distributor killed (with failover), a task deleted, the central baseline refusing changes, stop while someone waits" do
    hosts_before = length(Tartarus.hosts())

    job = fn id ->
      %{
        id: id,
        tasks: [%{name: "T1", resources: [:a]}, %{name: "T2", resources: [:b], after: ["T1"]}]
      }
    end

    {:ok, f} = Floor.start(robots: 2, resources: [:a, :b], scale: 0.005)

    assert {:error, "the distributor's host can be killed only" <> _} =
             Floor.change(f, {:kill_distributor, 10})

    {:ok, _} = Floor.stop(f)

    {:ok, f} = Floor.start(robots: 2, resources: [:a, :b], scale: 0.005, failover: true)
    assert :ok = Floor.submit(f, job.(1))
    assert :ok = Floor.change(f, {:kill_distributor, 30})
    assert :ok = Floor.change(f, {:delete, "T2"})
    for id <- 2..4, do: assert(:ok = Floor.submit(f, job.(id)))
    assert :ok = Floor.await(f, 20_000)
    {:ok, r} = Floor.stop(f)
    assert r.timed_out == [] and r.mutex_violations == 0
    assert [%{result: :ok}, %{result: :ok}] = r.changes

    {:ok, c} = Floor.start(robots: 2, resources: [:a, :b], design: :central, scale: 0.005)

    assert {:error, "the central baseline takes no on-the-fly changes"} =
             Floor.change(c, {:delete, "T2"})

    # a long job; stop/1 while a caller waits for it
    assert :ok =
             Floor.submit(c, %{
               id: 1,
               tasks: [%{name: "T1", resources: [:a], duration_ms: 400_000}]
             })

    # Stopped once the floor holds the waiter's call: its mailbox has the await before the stop.
    :erlang.trace(c, true, [:receive])
    %Task{pid: waiting} = waiter = Task.async(fn -> Floor.await(c, 60_000) end)
    assert_receive {:trace, ^c, :receive, {:"$gen_call", {^waiting, _}, {:await, 60_000}}}
    :erlang.trace(c, false, [:receive])
    {:ok, r} = Floor.stop(c)
    assert r.timed_out == [1]
    assert Task.await(waiter) == {:error, :stopped}
    eventually(fn -> length(Tartarus.hosts()) == hosts_before end)
  end

  test "a malformed job is refused before anything starts" do
    assert {:error, ~s(job 1 has no tasks)} = Floor.run(jobs: [%{id: 1, tasks: []}])

    assert {:error, "invalid options given to TartarusWarehouse.Floor.run/1 for key :robots" <> _} =
             Floor.run(robots: 0)
  end

  @tag timeout: 300_000
  @tag :property
  test "property: random jobs (sequences, independent sequences, shared resources), 1-6 robots, random durations, tasks added and deleted on the fly, a robot removal: no violation, every job completes" do
    resources = [:a, :b, :c, :d, :e]

    # A task: its resources (1-2 of five), its ideal duration, whether it follows the previous.
    task =
      {:proper_types.non_empty(:proper_types.list(:proper_types.elements(resources))),
       :proper_types.integer(500, 3000), :proper_types.boolean()}

    job = :proper_types.non_empty(:proper_types.list(task))

    # On-the-fly changes, after 0-3 jobs completed: add task X (resource :x) after T1..T3,
    # delete X, delete T2.
    otfp =
      :proper_types.oneof([
        {:insert, :proper_types.elements(["T1", "T2", "T3"])},
        :delete_x,
        :delete_t2
      ])

    gen =
      {:proper_types.integer(1, 6), :proper_types.non_empty(:proper_types.list(job)),
       :proper_types.integer(1, 1000), :proper_types.boolean(),
       :proper_types.list({:proper_types.integer(0, 3), otfp})}

    prop =
      :proper.forall(gen, fn {robots, raw_jobs, seed, removal, changes} ->
        Prop.safely(fn ->
          jobs =
            raw_jobs
            |> Enum.take(5)
            |> Enum.with_index(1)
            |> Enum.map(fn {tasks, id} ->
              %{
                id: id,
                tasks:
                  tasks
                  |> Enum.take(4)
                  |> Enum.with_index(1)
                  |> Enum.map(fn {{rs, ms, chained}, i} ->
                    %{
                      name: "T#{i}",
                      resources: rs,
                      duration_ms: ms,
                      after: if(chained and i > 1, do: ["T#{i - 1}"], else: [])
                    }
                  end)
              }
            end)

          retire = if removal and robots > 1, do: [{robots, 1}], else: []
          x = %{name: "X", resources: [:x], duration_ms: 700}

          events =
            changes
            |> Enum.take(3)
            |> Enum.map(fn
              {n, {:insert, after_task}} -> {n, {:insert, after_task, x}}
              {n, :delete_x} -> {n, {:delete, "X"}}
              {n, :delete_t2} -> {n, {:delete, "T2"}}
            end)

          {:ok, r} =
            Floor.run(
              robots: robots,
              jobs: jobs,
              scale: 0.005,
              jitter: 0.5,
              seed: seed,
              retire: retire,
              events: events,
              resources: [:x | resources],
              # a case takes well under 1 s; a hung one fails in 10 s, so shrinking a
              # counterexample fits in the test's time
              timeout_ms: 10_000
            )

          c = Checker.completion(r.history, jobs)

          r.timed_out == [] and Checker.violations(r.history) == [] and
            length(c.completed) == length(jobs)
        end)
      end)

    assert Prop.check(prop, 50) == true
  end
end
