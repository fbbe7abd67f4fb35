defmodule Mix.Tasks.Tartarus.Select do
  @shortdoc "Immune selection of the best solution per problem class (thesis ch. 6)"
  @moduledoc """
  Runs the immune-selection experiments of the thesis (§6.5) on emulated networks (see
  `TartarusImmune.Select` and `TartarusImmune.Experiment`): iPkts (mobile agents carrying
  sorting algorithms) are drawn by danger signals to the hosts where sequences wait to be
  sorted; the best algorithm for each class of sequences takes over the network.

      mix tartarus.select [--experiment table6_2|sharing|danger|fig6_8|otfp|nodes50|dynamic|influx|barrage|iot|fig6_4b|secondary|lspan]
                          [--seed 1] [--seeds 1] [--nodes 10] [--topology grid|ring|line]
                          [--mode virtual|peer] [--group 1] [--set p1|p2|p3|p4|temp]
                          [--steps 600] [--share 0.9] [--hold 30] [--eta 0.5] [--beta 5]
                          [--period 10] [--cost ops|comparisons] [--repeat-at 61]
                          [--out DIR] [--json]
                          [--dashboard PORT]

  `--dashboard PORT` serves the web dashboard on 127.0.0.1:PORT while the runs go (the
  address and token are printed): the hosts of the run going now and the immune panel
  (`TartarusImmune.Panel`: the round, live iPkts per solution, convergence, and per host
  its pending problems and queued iPkts by solution). `--help` prints this text.
  Experiments:

    * `table6_2`: P1-P4 on a 10-host grid, for `--seeds` seeds from `--seed`; the winner per
      set against the thesis's IS, QS, IS, QS (Table 6.2) and the known best (the lowest
      mean cost on the held-out instances);
    * `sharing`: `--set` (p2) with and without sharing (Fig. 6.11);
    * `danger`: `--set` (p2) with danger signals, without, and without sharing (Fig. 6.8);
    * `fig6_8`: the pre-registered Fig. 6.8 (docs/immune.md, 2026-11-27;
      `TartarusImmune.Select.Fig68`): the arms of `danger` on P4, a 50-host grid, β 10,
      Eq. 6.5's signal lifetimes, the initial iPkts (one of each solution) on 10 random
      hosts; run it with `--seed 1001 --seeds 40`. Its summary adds `preregistered`:
      deviations from the pre-registration (none for that command), per arm the rounds
      and events described, the Mann-Whitney p of signals < no signals, the guard against
      an uninformative configuration and the verdict (pass, fail or uninformative);
    * `otfp`: `--set` (p1) starting with Shell and Selection only; Quick, Insertion, Merge
      and Heap are added at steps 40, 80, 120, 160; runs all `--steps` (Fig. 6.4);
    * `nodes50`: P2 and P3 on `--nodes` hosts (default 50; also 100, 1000), Fig. 6.5;
    * `dynamic`: `--set` (p4) on 50 hosts that break off (all links down) or reconnect
      with probability p per step, p in 0, 0.1, 0.3, 0.5, 0.7, 1 (Fig. 6.6);
    * `influx`: η in 0.1, 0.3, 0.5, 0.7, 0.9 (Fig. 6.7a); `barrage`: β in 1, 2, 5, 10, 20
      (Fig. 6.7b);
    * `iot`: sequences of slowly varying temperature readings on 50 hosts (Fig. 6.10).

  Pre-registered on 2026-12-06 (docs/immune.md; each summary adds `preregistered`: the
  deviations from the registration, the measures and the verdict):

    * `fig6_4b`: `otfp` on P4 (Fig. 6.4b), 300 rounds; run it with `--seed 2001 --seeds
      20`; the mean learning curve (`fig6_4b.svg`) and whether Quick and Shell both hold a
      quarter of the iPkts at the end (`TartarusImmune.Select.Fig64b`);
    * `secondary`: Fig. 6.3a's secondary response: P1, one barrage at round 1 and its copy
      (same instances, same hosts) at `--repeat-at` (61), 120 rounds; the rounds until the
      losers are halved after each (`TartarusImmune.Select.Secondary`; `secondary.svg`,
      `secondary_suppression.svg`); run it with `--seed 3001 --seeds 30`;
    * `lspan`: `fig6_8`'s configuration with danger signals of span 2, 3 and 4 and without;
      every distressed host's reach time (rounds until an iPkt that recognizes its problems
      is there) measured (`TartarusImmune.Select.Lspan`; `reach_mean.svg`); run it with
      `--seed 4001 --seeds 20`, and with `--eta 0.1` for the second configuration.

  `--cost comparisons` is a labelled sensitivity option (the arms' names say
  "(comparisons)"): a sorting solution's cost is its key comparisons alone instead of
  comparisons + moves (`TartarusImmune.Sorting.Comparisons`).

  A step is one round of Algorithm 4 at every host (each host solves at most one waiting
  instance) followed by one move of every iPkt. A run stops when it has converged: one
  solution holds at least `--share` of all live iPkts for `--hold` consecutive steps (its
  first step is the convergence step), or after `--steps`.

  Output (in `--out DIR`, default `results/select-<experiment>-<UTC timestamp>`):
  `runs.csv`, `population_<arm>_<set>.svg|csv` (the learning curves of the first seed),
  `steps.svg` (box plots of convergence steps, when an arm has several seeds; likewise
  `events.svg`, `test_accuracy.svg`, `migrations.svg`), `summary.json`, `summary.md`. The
  runs go through `TartarusEmu.Sweep` (in parallel, a line per finished run on standard
  error).

  Summary keys: `experiment, winners` (set -> the winner of most seeds), `winners_by_seed,
  known_best, convergence_steps` (set -> per seed; for arms: arm -> per seed),
  `test_accuracy` (set -> mean fraction of held-out instances where the network's choice is
  the oracle's), `test_regret` (set -> mean extra cost over the oracle, comparisons +
  moves), `test_regret_rel, seeds, nodes, mode, wall_ms`; `table6_2` adds
  `thesis_best, seeds_matching_thesis, seeds_matching_known_best`; the others add `arms`
  (per arm: convergence steps, mean, sd, winners, accuracy, regret, migrations, run ms);
  all add `sweep` (`TartarusEmu.Sweep`: per-arm aggregates of `steps, events,
  test_accuracy, migrations` and, for `sharing` and `danger`, one-sided Mann-Whitney tests
  of fewer convergence steps with sharing / with danger signals).
  With `--json` the last line printed is the summary as one JSON object (the progress
  lines go to standard error as without it).
  """
  use TartarusTools.CLI

  alias TartarusImmune.Select

  @task "tartarus.select"

  @impl true
  def run(argv) do
    schema =
      Select.schema()
      |> Keyword.drop([:quiet, :etas, :betas, :add_at, :ps])
      |> Keyword.update!(:set, &Keyword.put(&1, :type, {:in, [:p1, :p2, :p3, :p4, :temp]}))
      |> Keyword.update!(:out, &Keyword.put(&1, :type, :string))
      |> Keyword.update!(:dashboard, &Keyword.put(&1, :type, :non_neg_integer))
      |> Keyword.put(:json, type: :boolean, default: false, doc: "print the summary as JSON")

    opts = TartarusTools.CLI.options!(argv, schema, @task)
    {exp, json?} = {opts[:experiment], opts[:json]}
    # progress goes to standard error, so it stays with --json (the JSON is on stdout)
    sel_opts = Keyword.drop(opts, [:json])

    case Select.validate(sel_opts) do
      {:ok, _} -> :ok
      {:error, message} -> TartarusTools.CLI.error!(@task, message)
    end

    Mix.Task.run("app.start")
    unless json?, do: Mix.shell().info("select: experiment #{exp}, seed #{opts[:seed]}...")

    case Select.run(sel_opts) do
      {:ok, %{summary: s, out: dir}} ->
        TartarusTools.CLI.report(s, [json: json?], fn s -> text(s, dir) end)

      {:error, message} ->
        TartarusTools.CLI.error!(@task, message)
    end
  end

  defp text(s, dir) do
    arms =
      case s do
        %{arms: arms} ->
          Enum.map_join(arms, "\n", fn {arm, a} ->
            "  #{arm}: convergence steps #{TartarusTools.CLI.show(a.convergence_steps)} (mean #{fmt(a.steps_mean)}, sd #{fmt(a.steps_sd)}), winners #{TartarusTools.CLI.show(a.winners)}"
          end)

        _ ->
          "  seeds matching the thesis (IS, QS, IS, QS): #{s.seeds_matching_thesis} of #{length(s.seeds)}"
      end

    """
    winners #{TartarusTools.CLI.show(s.winners)} (known best #{TartarusTools.CLI.show(s.known_best)})
    convergence steps #{TartarusTools.CLI.show(s.convergence_steps)}
    test accuracy #{TartarusTools.CLI.show(s.test_accuracy)}
    #{arms}
    written to #{dir}\
    """
  end

  defp fmt(nil), do: "-"
  defp fmt(x), do: :erlang.float_to_binary(x * 1.0, decimals: 1)
end
