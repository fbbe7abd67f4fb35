defmodule TartarusImmune.PathFollowing.Experiment do
  @moduledoc """
  The path-following experiment of thesis §6.5.11 (Fig. 6.13, Table 6.5): two robots on
  Path-1 and Path-2 at once learn which PFA to use on which kind of sub-path with the
  immune selection mechanism (`TartarusImmune.Node`, `TartarusImmune.IPkt`,
  `TartarusImmune.Maths`), sharing what they learn through iPkts (`mix tartarus.pfa`).

  This module is the door (options, `run/1`); the experiment is a `TartarusEmu.Sweep` of
  one arm (`"pfa"`) over the seeds `seed, seed + 1, ...`, a trial a seed, and its jobs
  are modules of their own:

  | job | module |
  |---|---|
  | one trial: the world, the network, the immune mechanism as the robots' policy | `TartarusImmune.PathFollowing.Experiment.Trial` |
  | the summary over the trials, the exhaustive reference, the files | `TartarusImmune.PathFollowing.Experiment.Summary` |

  Trials run one after another, each in its own process on its own network (a trial's
  numbers depend on its seed only; two at once would wait on each other's danger signals,
  `Tartarus.Signal.settle/1`). Besides its own files the sweep writes `runs.csv` (a row per
  trial: `arm, seed` and the metrics of
  `TartarusImmune.PathFollowing.Experiment.Summary.metrics/0`), a box plot per metric
  over the trials and the summary's `sweep` key (per metric n, mean, sd, median,
  quartiles).

  Choices (all options): μ = 0.8 rather than Table 6.1's 0.5, since with ψ_max = 2 (four
  features) μ = 0.5 lets an iPkt recognize sub-paths of other types (sp-a and sp-c, sp-b
  and sp-d and sp-a and sp-d are 0.67-0.79 apart; instances of one type at most 0.2);
  μ = 0.8 recognizes within 0.4. Q_max = 20 rather than 5, since a robot's host holds the
  iPkts of four sub-path types and up to eight PFAs, not one problem class. `:n_min`
  (default 1) is how many measures a PFA needs on a type before suppression can kill it
  (and until then it counts as untried); 2 was tried against single noisy measures and
  made the curves worse (seeds 1-10, last three laps: Path-1 31.6 s against 26.7 s,
  Path-2 52.2 s against 30.0 s): re-trying the losers costs more than the noise it
  removes.
  """

  alias Tartarus.Clock
  alias TartarusArena.PFAs
  alias TartarusEmu.Sweep
  alias TartarusImmune.Params
  alias TartarusImmune.PathFollowing.Experiment.{Summary, Trial}

  @schema [
    laps: [type: :pos_integer, default: 12, doc: "laps per robot"],
    trials: [type: :pos_integer, default: 10, doc: "trials (seeds seed, seed + 1, ...)"],
    seed: [type: :integer, default: 1, doc: "seed of the first trial"],
    pfas: [
      type: {:list, :atom},
      default: nil,
      doc: "the PFAs the input stream offers (default all eight)"
    ],
    sharing: [
      type: {:in, [:clones, true, false]},
      default: :clones,
      doc:
        "how mappings travel between the robots: :clones (fresh clones go to the other robot, the rest stay), true (every iPkt not held by a problem moves on), false (none)"
    ],
    explore: [
      type: {:or, [{:in, [:activation, :untried_first]}, :probability]},
      default: :untried_first,
      doc:
        "when a robot tries a PFA not yet measured on the sub-path's type: :activation (if its activation is at least the best measured one's), :untried_first (always, at once), or a probability"
    ],
    n_min: [
      type: :pos_integer,
      default: 1,
      doc: "measures of a PFA on a sub-path type before suppression can kill it"
    ],
    stream: [
      type: {:in, [:once, :lifelong]},
      default: :once,
      doc:
        "the input stream: :once (each PFA once per robot, nothing after the eighth) or :lifelong (then, each lap, one PFA whose mapping of some sub-path type has died out at the robot, for those types)"
    ],
    challenge: [
      type: {:in, [:tried, :activation]},
      default: :tried,
      doc:
        "a re-injected PFA: :tried (enters at tau_max, so it runs once) or :activation (tau_init, as a new one)"
    ],
    stuck_after: [
      type: {:range, 0.1, 3600},
      default: 6.0,
      doc:
        "seconds without 5 cm of progress after which the experimenter nudges a robot 10 cm on (Run.laps/3's :stuck_after)"
    ],
    lost_penalty: [
      type: {:range, 0, 3600},
      default: 5.0,
      doc: "seconds charged each time a robot is put back on the line or nudged on"
    ],
    danger: [type: :boolean, default: true, doc: "danger signals on"],
    exhaustive: [type: :boolean, default: true, doc: "also run the exhaustive search"],
    params: [
      type: :keyword,
      default: [],
      doc: "Table 6.1 parameters (TartarusImmune.Params); defaults here mu 0.8, q_max 20"
    ],
    out: [type: :any, default: nil, doc: "output directory, or false for none"],
    quiet: [type: :boolean, default: false, doc: "no line per finished trial"]
  ]

  @doc "The options of `run/1` (`Tartarus.Options` schema)."
  @spec schema() :: Tartarus.Options.schema()
  def schema, do: @schema

  @doc """
  Runs the trials and writes the outputs (unless `out: false`): `lap_times.csv` (trial,
  seed, path, lap, seconds), `lap_times_trial1.svg` (Fig. 6.13a), `lap_times_mean.svg`
  (Fig. 6.13b), `choices.csv` (every sub-path crossed: trial, robot, lap, index, type,
  PFA, time, on_line, normalized cost), `best_pfa.csv` (Table 6.5 beside the thesis and
  the exhaustive search), `summary.json`, `summary.md` (see
  `TartarusImmune.PathFollowing.Experiment.Summary`), and the sweep's `runs.csv` and box
  plots. A line per finished trial goes to standard error unless `quiet: true`. Options:

  #{Tartarus.Options.docs(@schema)}

  Returns `{:ok, %{summary: map, out: dir | nil, trials: [trial], files: [path]}}` (a
  trial as `TartarusImmune.PathFollowing.Experiment.Trial.run/3` returns it, in seed
  order) or `{:error, message}`.
  """
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  def run(opts \\ []) do
    with {:ok, o} <- Tartarus.Options.validate(opts, @schema, "#{inspect(__MODULE__)}.run/1"),
         o = Map.new(o),
         {:ok, p} <- Params.new(Keyword.merge([mu: 0.8, q_max: 20], o.params)),
         :ok <- check_pfas(o.pfas) do
      o = %{o | pfas: o.pfas || PFAs.all()}
      t0 = Clock.machine_time(:microsecond)
      trials = fn r -> Enum.map(r.runs, & &1.summary) end

      spec = %{
        name: "pfa",
        title: "Path-following selection (thesis §6.5.11)",
        arms: [{"pfa", o}],
        seeds: Enum.map(0..(o.trials - 1), &(o.seed + &1)),
        run: fn _arm, seed -> Trial.run(o, p, seed) end,
        metrics: Summary.metrics(),
        # one trial at a time: a trial waits for the platform's signals to settle
        # (Tartarus.Signal.settle/1 waits for every signal in the VM), so two at once
        # wait on each other (measured: 6 trials took 1.4-2x longer with 2 at a time)
        concurrency: 1,
        summary: fn r ->
          # the trials' wall time (the exhaustive reference is not part of it)
          wall = (Clock.machine_time(:microsecond) - t0) / 1.0e6
          exhaustive = if o.exhaustive, do: Summary.exhaustive(o.pfas, o.seed)
          Summary.summarize(o, trials.(r), exhaustive, wall)
        end,
        write: fn dir, r -> Summary.write(dir, o, trials.(r), r.summary) end,
        report: &Summary.report/1
      }

      {:ok, r} = Sweep.run(spec, out: o.out, quiet: o.quiet)
      {:ok, %{summary: r.summary, out: r.out, trials: trials.(r), files: r.files}}
    end
  end

  defp check_pfas(nil), do: :ok

  defp check_pfas(pfas) do
    if pfas != [] and Enum.all?(pfas, &(&1 in PFAs.all())),
      do: :ok,
      else:
        {:error,
         "invalid value for :pfas: expected PFA modules of TartarusArena.PFAs.all(), got: #{inspect(pfas)}"}
  end
end
