defmodule Mix.Tasks.Tartarus.Lats.Calibrate do
  @shortdoc "LATS: per-receiver RSSI calibration from standing-still reference recordings"
  @moduledoc """
  Learns each receiver's RSSI correction from reference recordings and writes the
  calibration file that `mix tartarus.lats --replay-log ... --calibration FILE` reads
  (`TartarusLats.Replay.Calibration`).

      mix tartarus.lats.calibrate --fingerprints DIR --devices FILE --out FILE
                                  [--kind offset|slope] [--json]

  `--fingerprints DIR` holds files `<receiver name>_<x>_<y>_<z>.<ext>` (the beacon standing
  at that point, one receiver's readings, `time, receiver, beacon, rssi`); `--devices` the
  receivers' positions (tetam `.dev` or CSV). One log-distance model is fitted to every
  receiver and point; each receiver gets an offset (`--kind offset`, the default) or an
  offset and a path-loss slope (`--kind slope`) that put its readings on that model. Prints
  the model and, per receiver, the correction and the RMS residual before and after; with
  `--json` that as one JSON object (with provenance) on the last line.
  """
  use TartarusTools.CLI, out: :file

  alias TartarusLats.Replay.{Calibration, Devices}

  @switches [fingerprints: :string, devices: :string, out: :string, kind: :string, json: :boolean]

  @impl true
  def run(argv) do
    task = "tartarus.lats.calibrate"
    opts = TartarusTools.CLI.parse!(argv, @switches, task)
    kind = TartarusTools.CLI.choice!(opts[:kind], [:offset, :slope], :kind, task, :offset)

    for key <- [:fingerprints, :devices, :out],
        opts[key] == nil,
        do: TartarusTools.CLI.error!(task, "missing --#{key}")

    unless File.dir?(opts[:fingerprints]),
      do:
        TartarusTools.CLI.error!(
          task,
          "--fingerprints: directory not found: #{opts[:fingerprints]}"
        )

    unless File.regular?(opts[:devices]),
      do: TartarusTools.CLI.error!(task, "--devices: file not found: #{opts[:devices]}")

    devices = Devices.read!(opts[:devices])
    points = Calibration.points(opts[:fingerprints], devices)

    if points == [],
      do:
        TartarusTools.CLI.error!(
          task,
          "--fingerprints: no reference recordings of these receivers"
        )

    cal = Calibration.fit(points, kind)
    Calibration.write!(opts[:out], cal)

    result = %{
      model: cal.model,
      kind: kind,
      points: length(points),
      receivers: cal.receivers,
      out: opts[:out]
    }

    TartarusTools.CLI.report(result, json: opts[:json])
  end
end
