import Config

# A release of the node (`MIX_ENV=prod mix release`) is configured at boot from one file,
# TARTARUS_CONFIG or /etc/tartarus/node.exs (see TartarusNode.Config). A bad file stops the
# boot with one line and status 1 (the release's env.sh has already checked it before the VM
# started, so this is the second look, e.g. for `bin/tartarus start` with another env.sh).
# Outside a release (mix, tests) nothing is read.
if System.get_env("RELEASE_NAME") &&
     System.get_env("RELEASE_COMMAND") in ~w(start start_iex daemon daemon_iex) do
  case TartarusNode.Config.read(TartarusNode.Config.path()) do
    {:ok, node_config} ->
      config :tartarus_node, :config, node_config

    {:error, line} ->
      IO.puts(:stderr, line)
      System.halt(1)
  end
end
