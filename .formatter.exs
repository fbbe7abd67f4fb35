[
  inputs: ["mix.exs", "config/*.exs", "test/**/*.{ex,exs}", "scripts/*.exs"],
  subdirectories: ["apps/*"]
]
