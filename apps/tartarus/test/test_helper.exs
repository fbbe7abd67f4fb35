# Tests tagged :known_bug show a bug in lib/ that is not fixed yet (none at the moment); run
# them with `mix test --only known_bug`. Tests tagged :model_long run the protocol model longer
# (`mix test --only model_long`).
ExUnit.start(capture_log: true, exclude: [:known_bug, :model_long])
