# Which tags run (TARTARUS_TESTS=default|quick|all): see Tartarus.TestSupport.Tags.
Tartarus.TestSupport.Tags.start(capture_log: true)
# The API tests read the dashboard with :httpc (inets is optional for the app itself).
{:ok, _} = Application.ensure_all_started(:inets)
ExUnit.start()
