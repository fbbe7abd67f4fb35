# Scale tests (100 peer nodes) run only with TARTARUS_SCALE=1; they need epmd and minutes.
exclude =
  if System.get_env("TARTARUS_SCALE") == "1" do
    []
  else
    IO.puts("Excluding :scale tests (set TARTARUS_SCALE=1 to run them)")
    [:scale]
  end

ExUnit.start(exclude: exclude)
