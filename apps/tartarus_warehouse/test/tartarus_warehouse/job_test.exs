defmodule TartarusWarehouse.JobTest do
  use ExUnit.Case, async: true
  doctest TartarusWarehouse.Job
  doctest TartarusWarehouse
  doctest TartarusWarehouse.Program
  doctest TartarusWarehouse.Roam
  doctest TartarusWarehouse.Experiment
  doctest TartarusWarehouse.Experiment.Jobs
  doctest TartarusWarehouse.Experiment.Scaling
  doctest TartarusWarehouse.Experiment.Kind
  doctest TartarusWarehouse.Experiment.Manet
  doctest TartarusWarehouse.Floor.Options
  doctest TartarusWarehouse.Floor.Build

  alias TartarusWarehouse.Job

  @world Job.world([:rack, :path, :pack, :stamp, :shelf], 2)

  defp t(name, rs, after_ \\ []), do: %{name: name, resources: rs, after: after_}
  defp names(seq), do: Enum.map(seq, fn b -> Enum.map(b.tasks, & &1.name) end)

  test "case A: only sequential tasks, one agent per task, one sequence" do
    {:ok, plan} =
      Job.plan(
        %{
          id: 1,
          tasks: [t("Fetch", [:rack]), t("Carry", [:path], "Fetch"), t("Pack", [:pack], "Carry")]
        },
        @world
      )

    assert plan.case == :a
    assert Enum.map(plan.sequences, &names/1) == [[["Fetch"], ["Carry"], ["Pack"]]]
  end

  test "case B: independent sequences are planned apart (they run concurrently)" do
    tasks = [
      t("Fetch", [:rack]),
      t("Carry", [:path], "Fetch"),
      t("Pack", [:pack], "Carry"),
      t("Stamp", [:stamp]),
      t("Place", [:shelf], "Stamp")
    ]

    {:ok, plan} = Job.plan(%{id: 2, tasks: tasks}, @world)
    assert plan.case == :b

    assert Enum.map(plan.sequences, &names/1) == [
             [["Fetch"], ["Carry"], ["Pack"]],
             [["Stamp"], ["Place"]]
           ]

    [first, second] = TartarusWarehouse.Distributor.assignments(plan) |> Enum.chunk_by(& &1.seq)

    assert Enum.map(first, &{&1.look_for, &1.next}) == [
             {:free, {2, 0, 1}},
             {{2, 0, 1}, {2, 0, 2}},
             {{2, 0, 2}, :free}
           ]

    assert Enum.map(second, &{&1.look_for, &1.next}) == [{:free, {2, 1, 1}}, {{2, 1, 1}, :free}]
  end

  test "case C: tasks sharing a resource are packed into one agent, with the tasks between them" do
    {:ok, plan} =
      Job.plan(
        %{
          id: 3,
          tasks: [t("T1", [:rack]), t("T2", [:rack, :path], "T1"), t("T3", [:pack], "T2")]
        },
        @world
      )

    assert plan.case == :c
    assert Enum.map(plan.sequences, &names/1) == [[["T1", "T2"], ["T3"]]]
    assert hd(hd(plan.sequences)).resources == [:path, :rack]

    {:ok, plan} =
      Job.plan(
        %{
          id: 4,
          tasks: [
            t("T1", [:rack]),
            t("T2", [:path], "T1"),
            t("T3", [:rack], "T2"),
            t("T4", [:pack], "T3")
          ]
        },
        @world
      )

    assert Enum.map(plan.sequences, &names/1) == [[["T1", "T2", "T3"], ["T4"]]]
  end

  test "case C: independent sequences that share a resource become one sequence" do
    {:ok, plan} =
      Job.plan(
        %{
          id: 5,
          tasks: [
            t("T1", [:rack]),
            t("T2", [:path], "T1"),
            t("T3", [:pack]),
            t("T4", [:path], "T3")
          ]
        },
        @world
      )

    assert plan.case == :c
    assert Enum.map(plan.sequences, &names/1) == [[["T1"], ["T2", "T3", "T4"]]]
  end

  describe "spec errors (nothing is planned)" do
    test "empty job" do
      assert Job.plan(%{id: "J", tasks: []}, @world) == {:error, ~s(job "J" has no tasks)}
    end

    test "not a job" do
      assert {:error, "expected a job with :id and :tasks" <> _} = Job.plan(%{tasks: []}, @world)

      assert {:error, ~s(job "J": expected :tasks to be a list) <> _} =
               Job.plan(%{id: "J", tasks: :x}, @world)

      assert {:error, ~s(job "J": expected a task with :name and :resources) <> _} =
               Job.plan(%{id: "J", tasks: [%{name: "T"}]}, @world)
    end

    test "unknown resource" do
      assert Job.plan(%{id: "J", tasks: [t("T1", [:rack]), t("T2", [:dock], "T1")]}, @world) ==
               {:error,
                ~s(task "T2" of job "J" needs unknown resource :dock (known: [:pack, :path, :rack, :shelf, :stamp]\))}
    end

    test "a task needing no resource" do
      assert Job.plan(%{id: "J", tasks: [t("T1", [])]}, @world) ==
               {:error, ~s(task "T1" of job "J" needs no resource)}
    end

    test "cycle" do
      tasks = [
        t("T1", [:rack], "T3"),
        t("T2", [:path], "T1"),
        t("T3", [:pack], "T2"),
        t("T4", [:shelf])
      ]

      assert Job.plan(%{id: "J", tasks: tasks}, @world) ==
               {:error, ~s(job "J": tasks "T1", "T2", "T3" form a cycle)}

      assert Job.plan(%{id: "J", tasks: [t("T1", [:rack], "T1")]}, @world) ==
               {:error, ~s(job "J": tasks "T1" form a cycle)}
    end

    test "unknown predecessor, duplicate names, joins and forks" do
      assert Job.plan(%{id: "J", tasks: [t("T1", [:rack], "T0")]}, @world) ==
               {:error, ~s(task "T1" of job "J" comes after unknown task "T0")}

      assert Job.plan(%{id: "J", tasks: [t("T1", [:rack]), t("T1", [:path])]}, @world) ==
               {:error, ~s(job "J" names tasks twice: "T1")}

      assert Job.plan(
               %{
                 id: "J",
                 tasks: [t("T1", [:rack]), t("T2", [:path]), t("T3", [:pack], ["T1", "T2"])]
               },
               @world
             ) ==
               {:error,
                ~s(task "T3" of job "J" comes after 2 tasks ("T1", "T2"\); a job's tasks form sequences)}

      assert Job.plan(
               %{
                 id: "J",
                 tasks: [t("T1", [:rack]), t("T2", [:path], "T1"), t("T3", [:pack], "T1")]
               },
               @world
             ) ==
               {:error,
                ~s(task "T1" of job "J" is followed by 2 tasks ("T2", "T3"\); a job's tasks form sequences)}
    end

    test "a resource no robot reaches, and a sequence no single robot can do" do
      world = Job.world([:rack, :path, :pack], %{r1: [:rack, :path], r2: [:path]})

      assert Job.plan(%{id: "J", tasks: [t("T1", [:rack]), t("T2", [:pack], "T1")]}, world) ==
               {:error,
                ~s(sequence T1 -> T2 of job "J" needs resource :pack, which no robot reaches)}

      world = Job.world([:rack, :path, :pack], %{r1: [:rack, :path], r2: [:pack]})

      assert Job.plan(%{id: "J", tasks: [t("T1", [:rack]), t("T2", [:pack], "T1")]}, world) ==
               {:error,
                ~s(sequence T1 -> T2 of job "J" needs resources [:pack, :rack], which no single robot reaches all of)}

      assert {:ok, _} = Job.plan(%{id: "J", tasks: [t("T1", [:rack]), t("T2", [:pack])]}, world)
    end

    test "names, predecessors, resources and ids of the wrong kind (each message names the field, what was expected and what arrived)" do
      assert Job.plan(%{id: "J", tasks: [%{name: %{a: 1}, resources: [:rack]}]}, @world) ==
               {:error,
                ~s(job "J": expected a task's :name to be a string or an atom, got: %{a: 1})}

      assert Job.plan(%{id: "J", tasks: [%{name: nil, resources: [:rack]}]}, @world) ==
               {:error, ~s(job "J": expected a task's :name to be a string or an atom, got: nil)}

      pid = self()

      assert Job.plan(%{id: "J", tasks: [t("T1", [:rack]), t("T2", [:path], [pid])]}, @world) ==
               {:error,
                ~s(task "T2" of job "J": expected :after to be a task's name or a list of them (strings or atoms\), got: [#{inspect(pid)}])}

      assert Job.plan(%{id: "J", tasks: [t("T1", [:rack, pid])]}, @world) ==
               {:error,
                ~s(task "T1" of job "J": expected :resources to be a list of resources (atoms, strings or other plain data; not nil, true, false, a pid, a reference, a port or a function\), got: [:rack, #{inspect(pid)}])}

      assert {:error,
              "expected a job's :id to be plain data (no pid, reference, port or function: it travels with the agents), got: {1, #PID<" <>
                _} = Job.plan(%{id: {1, pid}, tasks: [t("T1", [:rack])]}, @world)

      assert {:ok, _} = Job.plan(%{id: {:batch, 1}, tasks: [t(:T1, [:rack])]}, @world)
    end

    test "changes: one check for the floor and the distributor" do
      assert {:ok, {:insert, "T1", %{name: "X", resources: [:rack], after: []}}} =
               Job.change({:insert, :T1, %{name: :X, resources: [:rack]}}, @world)

      assert Job.change({:insert, "T1", %{name: "X", resources: [:dock]}}, @world) ==
               {:error,
                ~s(change {:insert, "T1", _}: task "X" needs unknown resource :dock (known: [:pack, :path, :rack, :shelf, :stamp]\))}

      assert {:error, ~s(change {:insert, "T1", _}: task "X": expected :duration_ms) <> _} =
               Job.change(
                 {:insert, "T1", %{name: "X", resources: [:rack], duration_ms: -1}},
                 @world
               )

      assert Job.change({:delete, "T1"}, @world) == {:ok, {:delete, "T1"}}
      assert Job.change({:retire, 2}, @world) == {:ok, {:retire, 2}}

      assert Job.change({:kill_distributor, -5}, @world) ==
               {:error,
                "change {:kill_distributor, _}: expected the ms the host stays down (a non-negative integer), got: -5"}

      assert {:error, "expected a change: " <> _} = Job.change({:retire, 1, 2}, @world)

      # the pure distributor refuses the same way, and is unchanged
      d = TartarusWarehouse.Distributor.new(@world)

      assert {:error, "change {:insert, \"T1\", _}: expected the task to insert" <> _} =
               TartarusWarehouse.Distributor.insert(d, "T1", "not a map")

      assert {:error, "change {:delete, _}: " <> _} = TartarusWarehouse.Distributor.delete(d, %{})
    end

    test "bad program and duration" do
      assert {:error,
              ~s(task "T1" of job "J": expected :program to be a module implementing TartarusWarehouse.Program, got: Enum)} =
               Job.plan(%{id: "J", tasks: [Map.put(t("T1", [:rack]), :program, Enum)]}, @world)

      assert {:error,
              ~s(task "T1" of job "J": expected :duration_ms to be a positive number, got: 0)} =
               Job.plan(%{id: "J", tasks: [Map.put(t("T1", [:rack]), :duration_ms, 0)]}, @world)
    end
  end
end
