# PropEr helpers live in an .exs (not compiled into the app), see DESIGN §9.
Code.require_file("support/prop.exs", __DIR__)
ExUnit.start()
