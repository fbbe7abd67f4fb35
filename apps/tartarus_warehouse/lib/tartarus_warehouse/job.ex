defmodule TartarusWarehouse.Job do
  @moduledoc """
  Jobs of the warehouse model (thesis §4.3) and their plan: the first half of the Job
  Distributor's work (Algorithm 2), as pure functions.

  ## Glossary

    * **resource** - a rack, an aisle, a packing station, a charger (`Ψ`): an atom or a
      string, used by one robot at a time;
    * **task** - a program (a module implementing `TartarusWarehouse.Program`) with the
      resources it needs, an ideal duration and the tasks it must follow (`after`);
    * **job** - tasks whose `after` relations form one or more **sequences** (chains): a
      sequence runs on one robot, task after task; independent sequences run concurrently
      on different robots (§4.5.5);
    * **block** - the tasks one agent carries. Tasks that share a resource are packed into
      one block (case C), with every task between them in their sequence, so the agent that
      carries them is the one token of that resource;
    * **world** - what the distributor knows: the resources and what each robot reaches.

  ## Spec

      %{id: "J1", tasks: [
        %{name: "T1", resources: [:bay], duration_ms: 2000},
        %{name: "T2", resources: [:rack], after: ["T1"], program: TartarusWarehouse.Program.Pick}
      ]}

  `program` defaults to `TartarusWarehouse.Program.Work`, `duration_ms` to 2000 (the
  thesis's ideal task), `after` to `[]`.

  ## Cases (§4.5.1)

    * `:a` - one sequence, one task per block;
    * `:b` - two or more independent sequences, one task per block;
    * `:c` - some block packs two or more tasks (they share a resource).

  Sequences of a job that share a resource become one sequence (the second after the
  first): the thesis's "all the tasks become interdependent".

      iex> world = TartarusWarehouse.Job.world([:a, :b, :c], 2)
      iex> {:ok, plan} = TartarusWarehouse.Job.plan(%{id: "J1", tasks: [
      ...>   %{name: "T1", resources: [:a]},
      ...>   %{name: "T2", resources: [:b], after: ["T1"]},
      ...>   %{name: "T3", resources: [:a], after: ["T2"]}]}, world)
      iex> {plan.case, Enum.map(hd(plan.sequences), &Enum.map(&1.tasks, fn t -> t.name end))}
      {:c, [["T1", "T2", "T3"]]}
  """

  @typedoc "A resource's name."
  @type resource :: atom() | String.t()

  @typedoc "A task after validation."
  @type task :: %{
          name: String.t(),
          resources: [resource()],
          after: [String.t()],
          program: module(),
          duration_ms: number()
        }

  @typedoc "The tasks one agent carries, and the union of their resources (sorted)."
  @type block :: %{tasks: [task()], resources: [resource()]}

  @typedoc "A job's plan: its case and its sequences of blocks."
  @type plan :: %{id: term(), case: :a | :b | :c, sequences: [[block()]]}

  @typedoc "Resources, and what each robot reaches."
  @type world :: %{resources: MapSet.t(resource()), robots: %{term() => MapSet.t(resource())}}

  @doc """
  A world of `resources` with robots `1..robots` that all reach every resource (a map
  `robot => resources` gives each robot its own reach).

      iex> TartarusWarehouse.Job.world([:a], 2).robots
      %{1 => MapSet.new([:a]), 2 => MapSet.new([:a])}
  """
  @spec world([resource()], pos_integer() | %{term() => [resource()]}) :: world()
  def world(resources, robots) when is_integer(robots) and robots > 0,
    do: world(resources, Map.new(1..robots, &{&1, resources}))

  def world(resources, robots) when is_map(robots),
    do: %{
      resources: MapSet.new(resources),
      robots: Map.new(robots, fn {r, reach} -> {r, MapSet.new(reach)} end)
    }

  @doc """
  Validates a job spec against `world` and plans it: sequences of blocks and the case.
  Returns `{:ok, plan}` or `{:error, message}`; a malformed spec changes nothing.

      iex> world = TartarusWarehouse.Job.world([:a], 1)
      iex> TartarusWarehouse.Job.plan(%{id: "J9", tasks: []}, world)
      {:error, "job \\"J9\\" has no tasks"}
      iex> TartarusWarehouse.Job.plan(%{id: "J9", tasks: [%{name: "T1", resources: [:z]}]}, world)
      {:error, "task \\"T1\\" of job \\"J9\\" needs unknown resource :z (known: [:a])"}
  """
  @spec plan(map(), world()) :: {:ok, plan()} | {:error, String.t()}
  def plan(spec, world) do
    with {:ok, id, tasks} <- shape(spec),
         {:ok, tasks} <- tasks(id, tasks),
         :ok <- unique(id, tasks),
         :ok <- known_resources(id, tasks, world),
         :ok <- known_predecessors(id, tasks),
         :ok <- acyclic(id, tasks),
         {:ok, chains} <- chains(id, tasks),
         chains = merge_sharing(chains),
         :ok <- reachable(id, chains, world) do
      sequences = Enum.map(chains, &blocks/1)
      {:ok, %{id: id, case: case_of(sequences), sequences: sequences}}
    end
  end

  # -- shape -----------------------------------------------------------------------

  defp shape(%{id: id, tasks: []}), do: {:error, "job #{inspect(id)} has no tasks"}
  defp shape(%{id: id, tasks: tasks}) when is_list(tasks), do: {:ok, id, tasks}

  defp shape(%{id: id, tasks: other}),
    do:
      {:error,
       "job #{inspect(id)}: expected :tasks to be a list of tasks, got: #{inspect(other)}"}

  defp shape(other),
    do: {:error, "expected a job with :id and :tasks, got: #{inspect(other, limit: 5)}"}

  defp tasks(id, tasks) do
    Enum.reduce_while(tasks, {:ok, []}, fn t, {:ok, acc} ->
      case task(id, t) do
        {:ok, t} -> {:cont, {:ok, [t | acc]}}
        error -> {:halt, error}
      end
    end)
    |> case do
      {:ok, acc} -> {:ok, Enum.reverse(acc)}
      error -> error
    end
  end

  defp task(id, %{name: name, resources: rs} = t) when is_list(rs) do
    name = to_string(name)
    after_ = t |> Map.get(:after, []) |> List.wrap() |> Enum.map(&to_string/1)
    program = Map.get(t, :program, TartarusWarehouse.Program.Work)
    duration = Map.get(t, :duration_ms, 2000)

    cond do
      rs == [] ->
        {:error, "task #{inspect(name)} of job #{inspect(id)} needs no resource"}

      not TartarusWarehouse.Program.program?(program) ->
        {:error,
         "task #{inspect(name)} of job #{inspect(id)}: expected :program to be a module implementing TartarusWarehouse.Program, got: #{inspect(program)}"}

      not (is_number(duration) and duration > 0) ->
        {:error,
         "task #{inspect(name)} of job #{inspect(id)}: expected :duration_ms to be a positive number, got: #{inspect(duration)}"}

      true ->
        {:ok,
         %{
           name: name,
           resources: Enum.uniq(rs),
           after: Enum.uniq(after_),
           program: program,
           duration_ms: duration
         }}
    end
  end

  defp task(id, other),
    do:
      {:error,
       "job #{inspect(id)}: expected a task with :name and :resources (a list), got: #{inspect(other, limit: 5)}"}

  defp unique(id, tasks) do
    case tasks |> Enum.frequencies_by(& &1.name) |> Enum.filter(fn {_, n} -> n > 1 end) do
      [] ->
        :ok

      dups ->
        {:error, "job #{inspect(id)} names tasks twice: #{names(Enum.map(dups, &elem(&1, 0)))}"}
    end
  end

  defp known_resources(id, tasks, world) do
    Enum.find_value(tasks, :ok, fn t ->
      case Enum.reject(t.resources, &MapSet.member?(world.resources, &1)) do
        [] ->
          nil

        [r | _] ->
          {:error,
           "task #{inspect(t.name)} of job #{inspect(id)} needs unknown resource #{inspect(r)} (known: #{inspect(Enum.sort(world.resources))})"}
      end
    end)
  end

  defp known_predecessors(id, tasks) do
    known = MapSet.new(tasks, & &1.name)

    Enum.find_value(tasks, :ok, fn t ->
      case Enum.reject(t.after, &MapSet.member?(known, &1)) do
        [] ->
          nil

        [p | _] ->
          {:error,
           "task #{inspect(t.name)} of job #{inspect(id)} comes after unknown task #{inspect(p)}"}
      end
    end)
  end

  # Kahn's algorithm (the thesis's §4.5.6 argument): what cannot be sorted lies on a cycle.
  defp acyclic(id, tasks) do
    indeg = Map.new(tasks, &{&1.name, length(&1.after)})
    succ = successors(tasks)
    ready = for {n, 0} <- indeg, do: n
    left = kahn(ready, indeg, succ)

    case left do
      [] -> :ok
      cyc -> {:error, "job #{inspect(id)}: tasks #{names(cyc)} form a cycle"}
    end
  end

  defp kahn([], indeg, _succ),
    do: indeg |> Enum.filter(fn {_, d} -> d > 0 end) |> Enum.map(&elem(&1, 0)) |> Enum.sort()

  defp kahn([n | rest], indeg, succ) do
    {ready, indeg} =
      Enum.reduce(Map.get(succ, n, []), {rest, Map.put(indeg, n, 0)}, fn s, {ready, indeg} ->
        d = indeg[s] - 1
        {if(d == 0, do: [s | ready], else: ready), Map.put(indeg, s, d)}
      end)

    kahn(ready, indeg, succ)
  end

  defp successors(tasks) do
    Enum.reduce(tasks, %{}, fn t, acc ->
      Enum.reduce(t.after, acc, fn p, acc -> Map.update(acc, p, [t.name], &(&1 ++ [t.name])) end)
    end)
  end

  # Sequences: every task has at most one predecessor and one successor.
  defp chains(id, tasks) do
    succ = successors(tasks)

    bad =
      Enum.find_value(tasks, fn t ->
        cond do
          length(t.after) > 1 ->
            "task #{inspect(t.name)} of job #{inspect(id)} comes after #{length(t.after)} tasks (#{names(t.after)}); a job's tasks form sequences"

          length(Map.get(succ, t.name, [])) > 1 ->
            "task #{inspect(t.name)} of job #{inspect(id)} is followed by #{length(succ[t.name])} tasks (#{names(succ[t.name])}); a job's tasks form sequences"

          true ->
            nil
        end
      end)

    if bad do
      {:error, bad}
    else
      by_name = Map.new(tasks, &{&1.name, &1})
      heads = Enum.filter(tasks, &(&1.after == []))
      {:ok, Enum.map(heads, &follow(&1, succ, by_name))}
    end
  end

  defp follow(t, succ, by_name) do
    case Map.get(succ, t.name, []) do
      [] -> [t]
      [next] -> [t | follow(by_name[next], succ, by_name)]
    end
  end

  # Sequences that share a resource run as one (in order of first appearance).
  defp merge_sharing(chains) do
    Enum.reduce(chains, [], fn chain, merged ->
      rs = resources(chain)

      case Enum.split_with(merged, &MapSet.disjoint?(resources(&1), rs)) do
        {_, []} -> merged ++ [chain]
        {apart, sharing} -> apart ++ [Enum.concat(sharing) ++ chain]
      end
    end)
  end

  defp resources(tasks), do: MapSet.new(Enum.flat_map(tasks, & &1.resources))

  defp reachable(id, chains, world) do
    Enum.find_value(chains, :ok, fn chain ->
      need = resources(chain)

      unless Enum.any?(world.robots, fn {_, reach} -> MapSet.subset?(need, reach) end) do
        missing =
          Enum.find(Enum.sort(need), fn r ->
            not Enum.any?(world.robots, fn {_, reach} -> MapSet.member?(reach, r) end)
          end)

        what =
          if missing,
            do: "resource #{inspect(missing)}, which no robot reaches",
            else: "resources #{inspect(Enum.sort(need))}, which no single robot reaches all of"

        {:error,
         "sequence #{Enum.map_join(chain, " -> ", & &1.name)} of job #{inspect(id)} needs #{what}"}
      end
    end)
  end

  # Packs a sequence into blocks: the span of every resource (first to last task using it)
  # is one block; overlapping spans merge.
  defp blocks(chain) do
    indexed = Enum.with_index(chain)

    spans =
      indexed
      |> Enum.flat_map(fn {t, i} -> Enum.map(t.resources, &{&1, i}) end)
      |> Enum.group_by(&elem(&1, 0), &elem(&1, 1))
      |> Enum.map(fn {_, is} -> {Enum.min(is), Enum.max(is)} end)

    # end of the block starting at each index
    reach = Enum.reduce(spans, %{}, fn {a, b}, acc -> Map.update(acc, a, b, &max(&1, b)) end)
    cut(indexed, reach, [])
  end

  defp cut([], _reach, acc), do: Enum.reverse(acc)

  defp cut([{_, i} | _] = rest, reach, acc) do
    stop = extend(i, Map.get(reach, i, i), reach)
    {taken, rest} = Enum.split_while(rest, fn {_, j} -> j <= stop end)
    tasks = Enum.map(taken, &elem(&1, 0))
    block = %{tasks: tasks, resources: tasks |> resources() |> Enum.sort()}
    cut(rest, reach, [block | acc])
  end

  defp extend(i, stop, _reach) when i >= stop, do: stop

  defp extend(i, stop, reach),
    do: extend(i + 1, max(stop, Map.get(reach, i + 1, i + 1)), reach)

  defp case_of(sequences) do
    cond do
      Enum.any?(sequences, fn s -> Enum.any?(s, &(length(&1.tasks) > 1)) end) -> :c
      length(sequences) > 1 -> :b
      true -> :a
    end
  end

  defp names(list), do: Enum.map_join(list, ", ", &inspect/1)
end
