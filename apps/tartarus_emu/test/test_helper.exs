# Scale tests (100 peer nodes) run only with TARTARUS_SCALE=1; they need epmd and minutes.
exclude =
  if System.get_env("TARTARUS_SCALE") == "1" do
    []
  else
    IO.puts("Excluding :scale tests (set TARTARUS_SCALE=1 to run them)")
    [:scale]
  end

# Browser tests (the dashboard in headless Chromium) run when Chromium is installed;
# scripts/test installs it and sets TARTARUS_BROWSER=1 so that a missing one fails loudly.
exclude =
  if TartarusTools.Dashboard.Browser.executable() || System.get_env("TARTARUS_BROWSER") == "1" do
    exclude
  else
    IO.puts("Excluding :browser tests (no chromium on the PATH; scripts/test installs it)")
    [:browser | exclude]
  end

ExUnit.start(exclude: exclude)
