# Top-level acceptance tests: real BEAM nodes started with :peer. Run by `mix test` at the
# umbrella root after every app's unit tests, or alone with `mix test.top`. Which tags run
# (TARTARUS_TESTS=default|quick|all): see Tartarus.TestSupport.Tags.
{_, 0} = System.cmd("epmd", ["-daemon"])
:ok = TartarusTools.Peer.ensure_distributed("tartarus_top")
Tartarus.TestSupport.Tags.start(capture_log: true, timeout: 300_000, autorun: false)
