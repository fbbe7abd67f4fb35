# Long runs are tagged :slow: excluded from a plain `mix test`, run by scripts/test (which
# sets TARTARUS_SLOW=1) and with TARTARUS_SCALE=1. A target not met yet is tagged
# :known_gap and excluded always (run it with --include known_gap).

exclude =
  if System.get_env("TARTARUS_SLOW") == "1" or System.get_env("TARTARUS_SCALE") == "1" do
    [:known_gap]
  else
    [:slow, :known_gap]
  end

ExUnit.start(capture_log: true, exclude: exclude)
