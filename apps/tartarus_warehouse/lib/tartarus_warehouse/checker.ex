defmodule TartarusWarehouse.Checker do
  @moduledoc """
  Checks a run's event log: the robots' execution histories (`TartarusWarehouse.Robot`),
  each entry one task executed by one robot from `start_us` to `stop_us` holding the
  task's resources.

    * `violations/1` - Eq. 4.1: at no instant do two robots hold one resource;
    * `completion/2` - every job completes: every task of every job ran exactly once, the
      tasks of a sequence on one robot, in their order;
    * `occupancy/3` - Eq. 4.2: how many robots execute over time (the pipeline's fill).

      iex> h = [%{robot: "r1", resources: [:a], start_us: 0, stop_us: 10, job: 1, task: "T1"},
      ...>      %{robot: "r2", resources: [:a], start_us: 5, stop_us: 15, job: 2, task: "T1"}]
      iex> [v] = TartarusWarehouse.Checker.violations(h)
      iex> {v.resource, v.robots}
      {:a, {"r1", "r2"}}
  """

  @typedoc "One execution (see `TartarusWarehouse.Robot`)."
  @type entry :: %{
          required(:robot) => term(),
          required(:resources) => [term()],
          required(:start_us) => integer(),
          required(:stop_us) => integer(),
          optional(atom()) => term()
        }

  @doc """
  Pairs of executions on different robots that hold one resource at the same instant
  (intervals are half-open: a robot may take a resource the instant another frees it).
  """
  @spec violations([entry()]) :: [%{resource: term(), robots: {term(), term()}, at_us: integer()}]
  def violations(history) do
    history
    |> Enum.reject(&Map.get(&1, :skipped, false))
    |> Enum.flat_map(fn e -> Enum.map(e.resources, &{&1, e}) end)
    |> Enum.group_by(&elem(&1, 0), &elem(&1, 1))
    |> Enum.sort()
    |> Enum.flat_map(fn {r, entries} ->
      entries
      |> Enum.sort_by(& &1.start_us)
      |> sweep([], [])
      |> Enum.map(fn {a, b} -> %{resource: r, robots: {a.robot, b.robot}, at_us: b.start_us} end)
    end)
  end

  defp sweep([], _active, found), do: Enum.reverse(found)

  defp sweep([e | rest], active, found) do
    active = Enum.filter(active, &(&1.stop_us > e.start_us))
    clashes = for a <- active, a.robot != e.robot, do: {a, e}
    sweep(rest, [e | active], Enum.reverse(clashes) ++ found)
  end

  @doc """
  Which jobs completed: `specs` are the job specs (validated); returns `completed` (ids),
  `missing` (`{job, task}` never run), `duplicated` (run more than once), `split`
  (`{job, sequence}` run on more than one robot), `out_of_order` (`{job, task}` that
  started before the task it comes after had finished). A job completes when none of its tasks is missing or
  duplicated and none of its sequences is split or out of order.
  """
  @spec completion([entry()], [map()]) :: map()
  def completion(history, specs) do
    by_job = Enum.group_by(history, & &1.job)

    results =
      Enum.map(specs, fn spec ->
        runs = Map.get(by_job, spec.id, [])
        names = Enum.map(spec.tasks, &to_string(&1.name))
        counts = Enum.frequencies_by(runs, & &1.task)
        missing = for n <- names, Map.get(counts, n, 0) == 0, do: {spec.id, n}
        dup = for {n, c} <- counts, c > 1, n in names, do: {spec.id, n}

        seqs = Enum.group_by(runs, &Map.get(&1, :seq))

        split =
          for {s, rs} <- seqs,
              rs |> Enum.map(& &1.robot) |> Enum.uniq() |> length() > 1,
              do: {spec.id, s}

        at = Map.new(runs, &{&1.task, &1})

        ooo =
          for t <- spec.tasks,
              p <- t |> Map.get(:after, []) |> List.wrap(),
              run = at[to_string(t.name)],
              before = at[to_string(p)],
              run != nil and before != nil and before.stop_us > run.start_us,
              do: {spec.id, to_string(t.name)}

        {spec.id, missing, dup, split, ooo}
      end)

    %{
      completed: for({id, [], [], [], []} <- results, do: id),
      missing: Enum.flat_map(results, &elem(&1, 1)),
      duplicated: Enum.flat_map(results, &elem(&1, 2)),
      split: Enum.flat_map(results, &elem(&1, 3)),
      out_of_order: Enum.flat_map(results, &elem(&1, 4))
    }
  end

  @doc """
  Robots executing over time, from `t0_us`, in buckets of `bucket_ms`: a list of
  `{bucket_start_ms, mean_busy_robots}`, and the mean over the whole run.

      iex> h = [%{robot: "r1", resources: [:a], start_us: 0, stop_us: 2000},
      ...>      %{robot: "r2", resources: [:b], start_us: 1000, stop_us: 2000}]
      iex> TartarusWarehouse.Checker.occupancy(h, 0, 1)
      %{series: [{0, 1.0}, {1, 2.0}], mean: 1.5}
  """
  @spec occupancy([entry()], integer(), pos_integer()) :: %{
          series: [{number(), float()}],
          mean: float()
        }
  def occupancy([], _t0, _bucket_ms), do: %{series: [], mean: 0.0}

  def occupancy(history, t0, bucket_ms) do
    stop = history |> Enum.map(& &1.stop_us) |> Enum.max()
    width = bucket_ms * 1000
    n = max(div(stop - t0 + width - 1, width), 1)

    series =
      for k <- 0..(n - 1) do
        lo = t0 + k * width
        hi = lo + width

        busy =
          Enum.reduce(history, 0, fn e, acc ->
            acc + max(0, min(e.stop_us, hi) - max(e.start_us, lo))
          end)

        {k * bucket_ms, Float.round(busy / width, 3)}
      end

    busy = Enum.reduce(history, 0, &(&2 + (&1.stop_us - &1.start_us)))
    %{series: series, mean: Float.round(busy / max(stop - t0, 1), 3)}
  end
end
