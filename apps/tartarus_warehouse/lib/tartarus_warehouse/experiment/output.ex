defmodule TartarusWarehouse.Experiment.Output do
  @moduledoc """
  The files every warehouse experiment writes beside the scenario's series and summary:
  what every robot executed, and Gantt charts of the runs the experiment names.
  """

  alias TartarusTools.{Report, SVG}

  @doc """
  Writes `executions.csv` (every task executed by every run: point, run, robot, job,
  task, resources, start, stop, ms; a point `{n, seed}` as `n/seed`) and two Gantt charts for each run the experiment
  `module` names (`c:TartarusWarehouse.Experiment.gantt/2`): a lane per robot, and a row per
  job as the thesis draws them (`<file>_by_job.svg`). Returns the paths written.
  """
  @spec write(map(), Path.t(), module()) :: [Path.t()]
  def write(state, dir, module) do
    rows =
      for r <- state.runs, e <- r.history do
        [
          point(r.point),
          r.kind,
          e.robot,
          e.job,
          e.task,
          Enum.join(Enum.map(e.resources, &inspect/1), " "),
          Float.round((e.start_us - r.t0_us) / 1000, 3),
          Float.round((e.stop_us - r.t0_us) / 1000, 3),
          Float.round(e.ms, 3)
        ]
      end

    csv =
      Report.write_csv!(
        dir,
        "executions",
        ["point", "run", "robot", "job", "task", "resources", "start_ms", "stop_ms", "ms"],
        rows
      )

    gantts =
      for r <- state.runs, {what, file} <- List.wrap(module.gantt(r, state)) do
        rows =
          Enum.map(r.robots, fn robot ->
            spans =
              for e <- r.history, e.robot == robot do
                %{
                  start: (e.start_us - r.t0_us) / 1000,
                  stop: (e.stop_us - r.t0_us) / 1000,
                  label: "J#{e.job}",
                  group: e.task
                }
              end

            %{label: robot, spans: spans}
          end)

        by_robot =
          SVG.write!(
            Path.join(dir, file),
            SVG.gantt(rows, title: "Warehouse: #{what}", x_label: "ms")
          )

        # As the thesis draws them: a row per job, bars coloured by robot, labelled with
        # the task and the ms it took.
        job_rows =
          Enum.map(r.jobs, fn job ->
            spans =
              for e <- r.history, e.job == job, not e.skipped do
                %{
                  start: (e.start_us - r.t0_us) / 1000,
                  stop: (e.stop_us - r.t0_us) / 1000,
                  label: "#{e.task} #{round(e.ms)}",
                  group: e.robot
                }
              end

            %{label: "J#{job}", spans: spans}
          end)

        by_job =
          SVG.write!(
            Path.join(dir, String.replace_suffix(file, ".svg", "_by_job.svg")),
            SVG.gantt(job_rows, title: "Warehouse: #{what}, by job", x_label: "ms")
          )

        [by_robot, by_job]
      end

    [csv | List.flatten(gantts)]
  end

  # A point as a CSV field: `{n, seed}` (scaling) as "n/seed".
  defp point(p) when is_tuple(p), do: p |> Tuple.to_list() |> Enum.join("/")
  defp point(p), do: p
end
