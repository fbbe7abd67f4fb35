# PropEr helpers live in an .exs (not compiled into the app). Long runs are tagged :slow
# and excluded unless TARTARUS_SCALE=1.
Code.require_file("support/prop.exs", __DIR__)

exclude =
  if System.get_env("TARTARUS_SCALE") == "1" do
    []
  else
    [:slow]
  end

ExUnit.start(capture_log: true, exclude: exclude)
