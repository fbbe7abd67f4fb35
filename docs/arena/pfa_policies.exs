# Regenerates docs/arena/pfa_policies.svg: the mean time per lap over 20 trials (seeds
# 1-20) of `mix tartarus.pfa` under two exploration policies, from the `lap_times.csv` of
# four runs (see docs/arena.md, "Figures"):
#
#   mix tartarus.pfa --seed 1  --out /tmp/pfa/default1
#   mix tartarus.pfa --seed 11 --out /tmp/pfa/default11
#   mix tartarus.pfa --seed 1  --explore activation --out /tmp/pfa/activation1
#   mix tartarus.pfa --seed 11 --explore activation --out /tmp/pfa/activation11
#   mix run docs/arena/pfa_policies.exs /tmp/pfa
#
# It also draws the first version's published means (activation, before the progress
# fix: the table in docs/arena.md's git history), given here as numbers.
[dir] = System.argv()

mean = fn runs, path ->
  rows =
    for run <- runs,
        line <- dir |> Path.join(run) |> Path.join("lap_times.csv") |> File.stream!() |> Enum.drop(1),
        [_trial, _seed, p, lap, secs] = line |> String.trim() |> String.split(","),
        p == path,
        do: {String.to_integer(lap), String.to_float(secs)}

  rows
  |> Enum.group_by(&elem(&1, 0), &elem(&1, 1))
  |> Enum.sort()
  |> Enum.map(fn {lap, ts} -> {lap, Enum.sum(ts) / length(ts)} end)
end

# before the progress fix (explore activation, stuck 15 s): seeds 1-10 and 11-20, averaged
old = %{
  "1" =>
    Enum.zip_with(
      [31.4, 31.3, 28.5, 30.4, 29.3, 29.3, 28.1, 29.4, 28.2, 28.8, 28.2, 28.5],
      [31.3, 30.3, 28.7, 30.1, 29.5, 28.4, 27.8, 28.2, 28.8, 27.8, 28.4, 28.1],
      &((&1 + &2) / 2)
    ),
  "2" =>
    Enum.zip_with(
      [51.2, 55.3, 35.8, 39.1, 44.0, 37.8, 39.5, 49.9, 47.6, 42.9, 41.2, 49.9],
      [43.3, 40.8, 35.6, 37.2, 40.9, 40.2, 39.9, 41.8, 39.0, 36.4, 41.8, 39.6],
      &((&1 + &2) / 2)
    )
}

series =
  for {path, label} <- [{"1", "Path-1"}, {"2", "Path-2"}],
      {name, runs} <- [
        {"default (untried first)", ["default1", "default11"]},
        {"explore activation", ["activation1", "activation11"]}
      ] do
    %{name: "#{label}, #{name}", points: mean.(runs, path)}
  end

old_series =
  for {path, label} <- [{"1", "Path-1"}, {"2", "Path-2"}] do
    %{
      name: "#{label}, first version (before the progress fix)",
      points: Enum.with_index(old[path], 1) |> Enum.map(fn {t, i} -> {i, t} end)
    }
  end

TartarusTools.SVG.write!(
  "docs/arena/pfa_policies.svg",
  TartarusTools.SVG.line_chart(series ++ old_series,
    title: "Mean time per lap, 20 trials (seeds 1-20): exploration policies",
    x_label: "lap",
    y_label: "seconds",
    y_min: 0
  )
)
