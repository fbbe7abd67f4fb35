# Browser tests (the dashboard in headless Chromium) run when Chromium is installed;
# scripts/test installs it and sets TARTARUS_BROWSER=1 so that a missing one fails loudly.
exclude =
  if TartarusTools.Dashboard.Browser.executable() || System.get_env("TARTARUS_BROWSER") == "1" do
    []
  else
    IO.puts("Excluding :browser tests (no chromium on the PATH; scripts/test installs it)")
    [:browser]
  end

ExUnit.start(capture_log: true, exclude: exclude)
