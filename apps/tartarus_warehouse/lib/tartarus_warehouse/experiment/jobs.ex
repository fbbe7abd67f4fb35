defmodule TartarusWarehouse.Experiment.Jobs do
  @moduledoc """
  The jobs the warehouse experiments run (`TartarusWarehouse.Experiment`): the thesis's
  warehouse jobs (T1-T4, §4.7.4), jobs of soft tasks (§4.7.2), jobs of independent
  sequences (§4.7.5), and a task program written while the warehouse runs (§4.5.4).
  """

  @doc """
  `n` jobs of the warehouse's four sequential tasks (§4.7.4): T1 leave the bay (`:bay`),
  T2 follow the line to the rack (`:line`, `:rack`), T3 follow the wall to the packing
  zone (`:wall`, `:packing`), T4 back to the bay's line (`:return`), each of ideal
  duration `ms`.

      iex> [j | _] = TartarusWarehouse.Experiment.Jobs.thesis_jobs(2, 2000)
      iex> Enum.map(j.tasks, & &1.name)
      ["T1", "T2", "T3", "T4"]
  """
  @spec thesis_jobs(pos_integer(), number()) :: [map()]
  def thesis_jobs(n, ms) do
    resources = [[:bay], [:line, :rack], [:wall, :packing], [:return]]

    for j <- 1..n do
      %{id: j, tasks: chain(Enum.zip(["T1", "T2", "T3", "T4"], resources), ms)}
    end
  end

  @doc """
  `n` jobs of `tasks` soft tasks each (§4.7.2: Sort, Merge, Add, Sub, Div repeating), task
  `i` needing resource `{:psi, i}`, each of ideal duration `ms`.

      iex> [j] = TartarusWarehouse.Experiment.Jobs.soft_jobs(1, 7, 2000)
      iex> {length(j.tasks), List.last(j.tasks).program}
      {7, TartarusWarehouse.Program.Merge}
  """
  @spec soft_jobs(pos_integer(), pos_integer(), number()) :: [map()]
  def soft_jobs(n, tasks, ms) do
    programs = TartarusWarehouse.Program.soft(tasks)

    for j <- 1..n do
      specs = for {p, i} <- Enum.with_index(programs, 1), do: {"T#{i}", [{:psi, i}], p}
      %{id: j, tasks: chain(specs, ms)}
    end
  end

  @doc """
  `n` jobs of §4.7.5 (Fig. 4.11): the first and the last purely sequential (T1-T4 of
  `thesis_jobs/2`), the others two independent sequences: Fetch -> Carry -> Pack (`:bay`,
  `:line`, `:packing`) and Stamp -> Place (`:stamp`, `:shelf`).

      iex> [a, b] = TartarusWarehouse.Experiment.Jobs.mixed_jobs(3, 2000) |> Enum.take(2)
      iex> {length(a.tasks), Enum.map(b.tasks, & &1.name)}
      {4, ["Fetch", "Carry", "Pack", "Stamp", "Place"]}
  """
  @spec mixed_jobs(pos_integer(), number()) :: [map()]
  def mixed_jobs(n, ms) do
    [seq | _] = thesis_jobs(1, ms)

    for j <- 1..n do
      if j == 1 or j == n do
        %{seq | id: j}
      else
        %{
          id: j,
          tasks:
            chain([{"Fetch", [:bay]}, {"Carry", [:line]}, {"Pack", [:packing]}], ms) ++
              chain([{"Stamp", [:stamp]}, {"Place", [:shelf]}], ms)
        }
      end
    end
  end

  @doc """
  `m` jobs of `n` independent tasks each (§4.5.5): no task after another, task `i`
  needing its own resource `{:psi, i}`, each of ideal duration `ms`; so each task is a
  sequence of its own, and task `i` of every job shares `{:psi, i}` (one agent, one token).

      iex> [j | _] = TartarusWarehouse.Experiment.Jobs.independent_jobs(2, 3, 2000)
      iex> Enum.map(j.tasks, &{&1.name, &1.resources, &1.after})
      [{"T1", [psi: 1], []}, {"T2", [psi: 2], []}, {"T3", [psi: 3], []}]
  """
  @spec independent_jobs(pos_integer(), pos_integer(), number()) :: [map()]
  def independent_jobs(m, n, ms) do
    for j <- 1..m do
      %{id: j, tasks: Enum.flat_map(1..n, &chain([{"T#{&1}", [{:psi, &1}]}], ms))}
    end
  end

  @doc """
  A task program written at run time (`TartarusWarehouse.Program.Detour`, compiled on
  first use): it ships with its agent as code.
  """
  @spec detour_program() :: module()
  def detour_program do
    module = TartarusWarehouse.Program.Detour

    if Code.ensure_loaded?(module) do
      module
    else
      {:ok, [^module]} =
        Tartarus.compile_string("""
        defmodule TartarusWarehouse.Program.Detour do
          @moduledoc "A detour from the usual path, written while the warehouse runs."
          use TartarusWarehouse.Program
          def work(data), do: Enum.reverse(data)
        end
        """)

      module
    end
  end

  defp chain(specs, ms) do
    specs
    |> Enum.with_index()
    |> Enum.map(fn {spec, i} ->
      {name, rs, program} =
        case spec do
          {name, rs} -> {name, rs, TartarusWarehouse.Program.Work}
          {name, rs, p} -> {name, rs, p}
        end

      prev = if i > 0, do: [elem(Enum.at(specs, i - 1), 0)], else: []
      %{name: name, resources: rs, after: prev, program: program, duration_ms: ms}
    end)
  end
end
