defmodule TartarusWarehouse.OtfpFiguresTest do
  # The on-the-fly experiment's two charts read back against the CSVs they were drawn from:
  # tasks per job (otfp.svg) and ms per task (otfp_ms.svg), each on its own labelled axis.
  use ExUnit.Case, async: false

  @moduletag :tmp_dir

  defp csv(dir, name) do
    [_ | rows] = dir |> Path.join(name) |> File.read!() |> String.split("\n", trim: true)

    for r <- rows,
        [k, v] = String.split(r, ","),
        do: {String.to_integer(k), elem(Float.parse(v), 0)}
  end

  defp drawn(svg, series) do
    for [x, y] <-
          Regex.scan(~r/<title>#{series}: \(([^,]+), ([^)]+)\)<\/title>/, svg,
            capture: :all_but_first
          ),
        do: {String.to_integer(x), elem(Float.parse(y), 0)}
  end

  defp y_title(svg),
    do: hd(Regex.run(~r/rotate\(-90[^>]*>([^<]+)</, svg, capture: :all_but_first))

  defp y_ticks(svg),
    do:
      for(
        [v] <- Regex.scan(~r/text-anchor="end">([^<]+)<\/text>/, svg, capture: :all_but_first),
        do: v
      )

  test "otfp.svg and otfp_ms.svg show the CSVs' numbers per job, each with its unit", %{
    tmp_dir: dir
  } do
    {:ok, _} =
      TartarusWarehouse.Experiment.run(
        experiment: :otfp,
        scale: 0.02,
        seed: 1,
        out: dir,
        quiet: true
      )

    tasks = csv(dir, "tasks_in_job.csv")
    ms = csv(dir, "ms_per_task.csv")
    assert length(tasks) == 16 and length(ms) == 16

    otfp = File.read!(Path.join(dir, "otfp.svg"))
    otfp_ms = File.read!(Path.join(dir, "otfp_ms.svg"))
    assert drawn(otfp, "tasks in the job") == tasks

    for {{j, v}, {dj, dv}} <- Enum.zip(ms, drawn(otfp_ms, "ms per task")),
        do: assert(j == dj and abs(v - dv) < 1.0e-3)

    assert length(drawn(otfp_ms, "ms per task")) == 16
    assert y_title(otfp) == "tasks"
    assert y_title(otfp_ms) == "time per task (ms)"
    # tasks are whole: integer ticks from 0; jobs (x) are whole too
    assert Enum.all?(y_ticks(otfp), &(Integer.parse(&1) |> elem(1) == ""))
    assert hd(y_ticks(otfp)) == "0" and hd(y_ticks(otfp_ms)) == "0"
    assert otfp =~ "on 4 robots, time scale 0.02, seed 1" and otfp_ms =~ "time scale 0.02, seed 1"
  end
end
