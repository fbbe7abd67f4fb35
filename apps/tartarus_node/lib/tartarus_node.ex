defmodule TartarusNode do
  @moduledoc """
  The deployable node: a `mix release` (`MIX_ENV=prod mix release`, see docs/devices.md)
  that boots from one configuration file (`TartarusNode.Config`) and runs one Tartarus host
  (`TartarusNode.Boot`).
  """

  @doc "The host this node runs (see `TartarusNode.Boot.host/0`)."
  @spec host() :: Tartarus.host()
  defdelegate host(), to: TartarusNode.Boot
end
