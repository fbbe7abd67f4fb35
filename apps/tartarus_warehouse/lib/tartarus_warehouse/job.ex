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
  thesis's ideal task), `after` to `[]`. Task names, `after` entries and resources are
  strings or atoms (not nil, true or false; a resource may also be other plain data, such as
  `{:psi, 1}`); the job's `id` is plain data (no pid,
  reference, port or function: it travels inside the agents).

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

  @typedoc "A resource's name: an atom or a string (any plain data is accepted, e.g. `{:psi, 1}`)."
  @type resource :: atom() | String.t() | term()

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

  @typedoc "A change to a running floor (see `change/2`)."
  @type change ::
          {:insert, String.t(), task()}
          | {:delete, String.t()}
          | {:retire, pos_integer()}
          | {:join, pos_integer()}
          | {:kill_distributor, non_neg_integer()}
          | {:disconnect, String.t()}
          | {:reconnect, String.t()}

  @doc """
  Validates a change to a running floor (`TartarusWarehouse.Floor.change/2`, the `events`
  of `TartarusWarehouse.Floor.run/1`) against `world`: the one check every door uses (the
  floor, the distributor). Returns `{:ok, change}` (task names as strings; an inserted
  task validated like a job's task, its resources known and reached by some robot) or
  `{:error, message}` naming what was expected and what arrived; nothing changes.

    * `{:insert, after_task, task_spec}` - add a task after the task named `after_task`;
    * `{:delete, task}` - delete a task;
    * `{:retire, i}`, `{:join, i}` - robot `i` (a positive integer) leaves, joins;
    * `{:kill_distributor, down_ms}` - kill the distributor's host for `down_ms` ms;
    * `{:disconnect, node}`, `{:reconnect, node}` - a node of the network (a robot `"r<i>"`
      or a secondary node `"s<i>"`, a string) leaves it (every link of it down) or rejoins
      it (§4.3: the network is a MANET).

  Whether robot `i` exists, and whether it may leave, is for the floor to say.

      iex> world = TartarusWarehouse.Job.world([:a, :detour], 2)
      iex> TartarusWarehouse.Job.change({:insert, :T1, %{name: "X", resources: [:detour]}}, world)
      ...> |> elem(1) |> Tuple.delete_at(2)
      {:insert, "T1"}
      iex> TartarusWarehouse.Job.change({:insert, "T1", "not a map"}, world)
      {:error, ~s[change {:insert, "T1", _}: expected the task to insert to be a map with :name and :resources (a list), got: "not a map"]}
      iex> TartarusWarehouse.Job.change({:retire, "2"}, world)
      {:error, ~s[change {:retire, _}: expected a robot's index (a positive integer), got: "2"]}
  """
  @spec change(term(), world()) :: {:ok, change()} | {:error, String.t()}
  def change({:insert, after_task, spec}, world) do
    with {:ok, after_task} <- change_name(:insert, "the task to insert after", after_task),
         :ok <- insert_shape(after_task, spec),
         {:ok, name} <- task_name({:otfp, after_task}, spec.name),
         {:ok, plan} <- plan(%{id: {:otfp, name}, tasks: [Map.put(spec, :after, [])]}, world) do
      [%{tasks: [task]}] = hd(plan.sequences)
      {:ok, {:insert, after_task, task}}
    else
      {:error, "change " <> _} = error ->
        error

      {:error, message} ->
        {:error, "change {:insert, #{inspect(after_task)}, _}: #{insert_message(message)}"}
    end
  end

  def change({:delete, task}, _world) do
    with {:ok, task} <- change_name(:delete, "a task's name", task), do: {:ok, {:delete, task}}
  end

  def change({what, i}, _world) when what in [:retire, :join] do
    if is_integer(i) and i > 0,
      do: {:ok, {what, i}},
      else:
        {:error,
         "change {#{inspect(what)}, _}: expected a robot's index (a positive integer), got: #{inspect(i, limit: 5)}"}
  end

  def change({:kill_distributor, ms}, _world) do
    if is_integer(ms) and ms >= 0,
      do: {:ok, {:kill_distributor, ms}},
      else:
        {:error,
         "change {:kill_distributor, _}: expected the ms the host stays down (a non-negative integer), got: #{inspect(ms, limit: 5)}"}
  end

  def change({what, node}, _world) when what in [:disconnect, :reconnect] do
    if is_binary(node) and node != "jd",
      do: {:ok, {what, node}},
      else:
        {:error,
         "change {#{inspect(what)}, _}: expected a robot's or a secondary node's name (a string such as \"r2\" or \"s1\"; the distributor's node leaves only by {:kill_distributor, ms}), got: #{inspect(node, limit: 5)}"}
  end

  def change(other, _world),
    do:
      {:error,
       "expected a change: {:insert, after_task, task_spec}, {:delete, task}, {:retire, robot}, {:join, robot}, {:kill_distributor, down_ms}, {:disconnect, node} or {:reconnect, node}, got: #{inspect(other, limit: 5)}"}

  defp change_name(what, expected, name) do
    if name?(name),
      do: {:ok, to_string(name)},
      else:
        {:error,
         "change {#{inspect(what)}, _}: expected #{expected} (a string or an atom), got: #{inspect(name, limit: 5)}"}
  end

  defp insert_shape(after_task, spec) do
    if is_map(spec) and Map.has_key?(spec, :name) and is_list(Map.get(spec, :resources)),
      do: :ok,
      else:
        {:error,
         "change {:insert, #{inspect(after_task)}, _}: expected the task to insert to be a map with :name and :resources (a list), got: #{inspect(spec, limit: 5)}"}
  end

  # The plan's messages name the inserted task's job `{:otfp, name}`: say it plainly.
  defp insert_message(message),
    do: String.replace(message, ~r/ of job \{:otfp, "[^"]*"\}|job \{:otfp, "[^"]*"\}: /, "")

  # -- shape -----------------------------------------------------------------------

  defp shape(%{id: id, tasks: tasks}) do
    cond do
      not plain?(id) ->
        {:error,
         "expected a job's :id to be plain data (no pid, reference, port or function: it travels with the agents), got: #{inspect(id, limit: 5)}"}

      tasks == [] ->
        {:error, "job #{inspect(id)} has no tasks"}

      is_list(tasks) ->
        {:ok, id, tasks}

      true ->
        {:error,
         "job #{inspect(id)}: expected :tasks to be a list of tasks, got: #{inspect(tasks, limit: 5)}"}
    end
  end

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
    with {:ok, name} <- task_name(id, name),
         {:ok, after_} <- after_names(id, name, Map.get(t, :after, [])) do
      task(id, name, rs, after_, t)
    end
  end

  defp task(id, other),
    do:
      {:error,
       "job #{inspect(id)}: expected a task with :name and :resources (a list), got: #{inspect(other, limit: 5)}"}

  defp task(id, name, rs, after_, t) do
    program = Map.get(t, :program, TartarusWarehouse.Program.Work)
    duration = Map.get(t, :duration_ms, 2000)

    cond do
      rs == [] ->
        {:error, "task #{inspect(name)} of job #{inspect(id)} needs no resource"}

      not (plain?(rs) and Enum.all?(rs, &(&1 not in [nil, true, false]))) ->
        {:error,
         "task #{inspect(name)} of job #{inspect(id)}: expected :resources to be a list of resources (atoms, strings or other plain data; not nil, true, false, a pid, a reference, a port or a function), got: #{inspect(rs, limit: 5)}"}

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

  defp task_name(id, name) do
    if name?(name),
      do: {:ok, to_string(name)},
      else:
        {:error,
         "job #{inspect(id)}: expected a task's :name to be a string or an atom, got: #{inspect(name, limit: 5)}"}
  end

  defp after_names(id, name, after_) do
    list = List.wrap(after_)

    if all_names?(list),
      do: {:ok, Enum.map(list, &to_string/1)},
      else:
        {:error,
         "task #{inspect(name)} of job #{inspect(id)}: expected :after to be a task's name or a list of them (strings or atoms), got: #{inspect(after_, limit: 5)}"}
  end

  # A task's or a resource's name: a non-empty string, or an atom other than nil, true, false.
  defp name?(n) when is_binary(n), do: n != ""
  defp name?(n) when is_atom(n), do: n not in [nil, true, false]
  defp name?(_), do: false

  defp all_names?([]), do: true
  defp all_names?([h | t]), do: name?(h) and all_names?(t)
  defp all_names?(_improper), do: false

  # Data that can travel with an agent and be compared: no pid, reference, port or function.
  defp plain?(x) when is_pid(x) or is_reference(x) or is_port(x) or is_function(x), do: false
  defp plain?(x) when is_list(x), do: plain_list?(x)
  defp plain?(x) when is_tuple(x), do: x |> Tuple.to_list() |> plain_list?()
  defp plain?(%{} = x), do: Enum.all?(x, fn {k, v} -> plain?(k) and plain?(v) end)
  defp plain?(_), do: true

  # Improper lists too.
  defp plain_list?([]), do: true
  defp plain_list?([h | t]), do: plain?(h) and plain_list?(t)
  defp plain_list?(t), do: plain?(t)

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
