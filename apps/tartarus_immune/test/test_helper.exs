# Long runs are tagged :slow and excluded unless TARTARUS_SCALE=1; a target not met yet is
# tagged :known_gap and excluded always (run it with --include known_gap).

exclude =
  if System.get_env("TARTARUS_SCALE") == "1" do
    [:known_gap]
  else
    [:slow, :known_gap]
  end

ExUnit.start(capture_log: true, exclude: exclude)
