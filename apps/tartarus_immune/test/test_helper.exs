# Long runs are tagged :slow and excluded unless TARTARUS_SCALE=1.

exclude =
  if System.get_env("TARTARUS_SCALE") == "1" do
    []
  else
    [:slow]
  end

ExUnit.start(capture_log: true, exclude: exclude)
