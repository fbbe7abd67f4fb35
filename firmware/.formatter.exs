[inputs: ["{mix,.formatter}.exs", "{config,lib}/**/*.{ex,exs}", "rootfs_overlay/etc/iex.exs"]]
