defmodule TartarusWarehouse.Program do
  @moduledoc """
  Task programs: the code a task agent carries and a robot executes (thesis §4.5.2: "the
  agent provides the code for the task to the robot").

  A program is a module with `run/1`. It ships with its agent as code (the agent adds it to
  the modules it carries), so a robot needs no program beforehand, and a program compiled
  at run time (`Tartarus.compile_string/1`) travels the same way (on-the-fly programming).

  The robot (`TartarusWarehouse.Robot`) calls `run(ctx)` with `ctx.ms`, how long the task
  should take on this robot (its ideal duration times the time scale and the robot's pace),
  and measures how long it really took. `use TartarusWarehouse.Program` gives a `run/1`
  that does the program's `work/1` on a little data and waits out the rest of `ctx.ms`.

      defmodule Sort do
        use TartarusWarehouse.Program
        def work(data), do: Enum.sort(data)
      end
  """

  @typedoc "What a program is told: the job, the task, the robot and the time it should take."
  @type ctx :: %{job: term(), task: String.t(), robot: term(), ms: number()}

  @doc "Executes the task; returns anything (the robot records only the time)."
  @callback run(ctx()) :: term()

  @doc false
  defmacro __using__(_opts) do
    quote do
      @behaviour TartarusWarehouse.Program

      @impl TartarusWarehouse.Program
      def run(ctx), do: TartarusWarehouse.Program.timed(ctx, &work/1)
    end
  end

  @doc """
  True if `module` is a program.

      iex> TartarusWarehouse.Program.program?(TartarusWarehouse.Program.Sort)
      true
      iex> TartarusWarehouse.Program.program?(Enum)
      false
  """
  @spec program?(term()) :: boolean()
  def program?(module) when is_atom(module),
    do: Code.ensure_loaded?(module) and function_exported?(module, :run, 1)

  def program?(_), do: false

  @doc """
  Runs `work` on a small list, then waits until `ctx.ms` have passed since the start.
  Returns what `work` returned.
  """
  @spec timed(ctx(), (list() -> term())) :: term()
  def timed(ctx, work) do
    t0 = Tartarus.Clock.monotonic_time(:microsecond)
    result = work.(Enum.to_list(100..1//-1))
    left = round(ctx.ms - (Tartarus.Clock.monotonic_time(:microsecond) - t0) / 1000)
    if left > 0, do: Tartarus.Clock.sleep(left)
    result
  end

  @doc """
  The soft tasks of the thesis's comparison (§4.7.2), repeating: Sort, Merge, Add, Sub, Div.

      iex> TartarusWarehouse.Program.soft(7) |> Enum.map(&Module.split/1) |> Enum.map(&List.last/1)
      ["Sort", "Merge", "Add", "Sub", "Div", "Sort", "Merge"]
  """
  @spec soft(pos_integer()) :: [module()]
  def soft(n) do
    programs = [__MODULE__.Sort, __MODULE__.Merge, __MODULE__.Add, __MODULE__.Sub, __MODULE__.Div]
    Enum.map(0..(n - 1), &Enum.at(programs, rem(&1, 5)))
  end
end

defmodule TartarusWarehouse.Program.Work do
  @moduledoc "A task that only takes its time (a robot moving along a path, say)."
  use TartarusWarehouse.Program
  @doc false
  def work(_data), do: :ok
end

defmodule TartarusWarehouse.Program.Sort do
  @moduledoc "Soft task: sorts data."
  use TartarusWarehouse.Program
  @doc false
  def work(data), do: Enum.sort(data)
end

defmodule TartarusWarehouse.Program.Merge do
  @moduledoc "Soft task: merges two sorted halves."
  use TartarusWarehouse.Program
  @doc false
  def work(data) do
    {a, b} = Enum.split(Enum.sort(data), div(length(data), 2))
    :lists.merge(a, b)
  end
end

defmodule TartarusWarehouse.Program.Add do
  @moduledoc "Soft task: adds data."
  use TartarusWarehouse.Program
  @doc false
  def work(data), do: Enum.sum(data)
end

defmodule TartarusWarehouse.Program.Sub do
  @moduledoc "Soft task: subtracts data."
  use TartarusWarehouse.Program
  @doc false
  def work(data), do: Enum.reduce(data, 0, &(&2 - &1))
end

defmodule TartarusWarehouse.Program.Div do
  @moduledoc "Soft task: divides data."
  use TartarusWarehouse.Program
  @doc false
  def work(data), do: Enum.map(data, &(&1 / 3))
end
