# PropEr helpers live in an .exs (not compiled into the app), see DESIGN §9. Long runs are
# tagged :scale and excluded unless TARTARUS_SCALE=1.
Code.require_file("support/prop.exs", __DIR__)

exclude =
  if System.get_env("TARTARUS_SCALE") == "1" do
    []
  else
    [:scale]
  end

ExUnit.start(capture_log: true, exclude: exclude)
