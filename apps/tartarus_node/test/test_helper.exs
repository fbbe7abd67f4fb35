# Which tags run (TARTARUS_TESTS=default|quick|all): see Tartarus.TestSupport.Tags.
Tartarus.TestSupport.Tags.start(capture_log: true)
