# Long runs are tagged :scale and excluded unless TARTARUS_SCALE=1.

exclude =
  if System.get_env("TARTARUS_SCALE") == "1" do
    []
  else
    [:scale]
  end

ExUnit.start(capture_log: true, exclude: exclude)
