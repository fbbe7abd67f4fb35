defmodule TartarusWarehouse.Experiment do
  @moduledoc """
  Jobs of the thesis's experiments.
  """

  @doc """
  `n` jobs of the warehouse's four sequential tasks (§4.7.4): T1 leave the bay (`:bay`),
  T2 follow the line to the rack (`:line`, `:rack`), T3 follow the wall to the packing
  zone (`:wall`, `:packing`), T4 back to the bay's line (`:return`), each of ideal
  duration `ms`.

      iex> [j | _] = TartarusWarehouse.Experiment.thesis_jobs(2, 2000)
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

      iex> [j] = TartarusWarehouse.Experiment.soft_jobs(1, 7, 2000)
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
