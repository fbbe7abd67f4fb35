defmodule TartarusDashboard.Emulation do
  @moduledoc """
  What an emulator gives the dashboard: the hosts and links it emulates (on any BEAM node,
  up or down) and the link actions. The emulator (`apps/tartarus_emu`) implements it over
  `TartarusEmu.Network`; the dashboard is given `emulation: {module, arg}`.

  Without an emulation the dashboard shows this node's hosts (`Tartarus.hosts/0`) and the
  neighbour links among them, and refuses link actions (404 `not_emulated`).

  Host ids are strings that name a host uniquely (a topology node's name); the page and the
  JSON API use them. A host's `:floor` (optional) draws each floor beside the others.
  """

  @typedoc "A host as the emulation names it."
  @type host :: %{
          required(:id) => String.t(),
          required(:host) => Tartarus.host(),
          required(:up) => boolean(),
          optional(:pos) => {number(), number()} | nil,
          optional(:floor) => integer() | nil
        }

  @typedoc "An edge of the topology: `up` is false when it is broken or an end is down."
  @type link :: %{a: String.t(), b: String.t(), up: boolean()}

  @typedoc "A link action."
  @type action :: :break_link | :heal_link | :isolate | :rejoin

  @doc "The hosts, in a stable order."
  @callback hosts(arg :: term()) :: [host()]

  @doc "The topology's edges and whether each is live."
  @callback links(arg :: term()) :: [link()]

  @doc """
  Carries out an action: `:break_link` and `:heal_link` get `%{a: id, b: id}`, `:isolate`
  and `:rejoin` get `%{host: id}` (ids of `c:hosts/1`, already checked to exist).
  """
  @callback act(arg :: term(), action(), params :: map()) :: :ok | {:error, term()}
end
