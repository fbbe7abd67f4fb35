defmodule TartarusTools.Bench.Profile do
  @moduledoc """
  `:eprof` around a stretch of a benchmark, on the node where it is called: every process
  of the node is profiled, and so is every process they spawn (a migration's new agent
  process, spawned by the host's supervisor, is counted).

      :ok = TartarusTools.Bench.Profile.start()
      # ... the work ...
      %{total_us: _, top: lines} = TartarusTools.Bench.Profile.stop(25)

  `top` holds the `n` functions that took the most time, costliest first, as eprof prints
  them (`module:function/arity  calls  %  time_us  us_per_call`). Profiling slows the
  profiled node several times: its figures rank costs, they are not timings.
  """

  @doc "Starts profiling every process of this node (and their children)."
  @spec start() :: :ok | {:error, term()}
  def start do
    _ = :eprof.start()

    case :eprof.start_profiling(:erlang.processes(), {:_, :_, :_}, [{:set_on_spawn, true}]) do
      :profiling -> :ok
      error -> {:error, error}
    end
  end

  @doc """
  Stops profiling and returns the `n` costliest functions (by own time, all processes
  together) and the total profiled time.
  """
  @spec stop(pos_integer()) :: %{total_us: non_neg_integer(), top: [String.t()]}
  def stop(n) do
    _ = :eprof.stop_profiling()
    path = Path.join(System.tmp_dir!(), "tartarus_eprof_#{System.unique_integer([:positive])}")
    :eprof.log(String.to_charlist(path))
    :eprof.analyze(:total, [{:sort, :time}])
    :eprof.stop()
    text = File.read!(path)
    File.rm(path)

    lines =
      text
      |> String.split("\n")
      |> Enum.filter(&Regex.match?(~r/^\S+:\S+\/\d+\s+\d+\s+[\d.]+\s+\d+/, &1))
      |> Enum.map(&String.trim/1)

    total =
      lines
      |> Enum.map(fn l -> l |> String.split() |> Enum.at(3) |> String.to_integer() end)
      |> Enum.sum()

    %{total_us: total, top: lines |> Enum.reverse() |> Enum.take(n)}
  end
end
