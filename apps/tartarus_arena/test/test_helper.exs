# PropEr helpers live in an .exs (not compiled into the app).
Code.require_file("support/prop.exs", __DIR__)
ExUnit.start(capture_log: true)
