defmodule Tartarus.Transport do
  @moduledoc """
  What a link costs beyond the real network: a behaviour for emulations, which the platform
  calls at two places and which only an emulator installs. None is installed by default: a
  deployed node pays one `:persistent_term` read per hand-off and per message for it.

    * `c:hand_off/3`: the source of a move or clone calls it before it sends `prepare`. It
      may delay the hand-off (the latency of its three messages) or fail it
      (`{:error, reason, rng}`: the agent's move fails with `reason`, and the agent hears of
      it in `handle_move_failed/4`). `rng` is the agent's own random stream, so that runs
      are reproducible.
    * `c:message_delay/2`: an agent that sends a message to an agent on another host
      (`Tartarus.post/3`, `cast/3`, `request/3` called from its callbacks) waits that many
      milliseconds before it reaches the receiver and again after (the acknowledgement or
      the reply).

  The link properties given to `Tartarus.connect/3` (`:latency_ms`, `:loss`) are kept by
  the two hosts for a transport to read (`link/2`); the platform itself does nothing else
  with them. The emulation app's transport applies them, and the emulator installs it on
  every node whose hosts it links with latency or loss.
  """

  @typedoc "A host as the platform passes it to a transport (its `ref` is its address)."
  @type host :: %{required(:ref) => Tartarus.host(), optional(atom()) => term()}

  @doc "Before a hand-off from `host` to `dest`: `{:ok, rng}` to go on, or an error."
  @callback hand_off(host(), dest :: Tartarus.host(), rng :: Tartarus.Random.t()) ::
              {:ok, Tartarus.Random.t()} | {:error, term(), Tartarus.Random.t()}

  @doc "The one-way delay, in ms, of a message from an agent on `from` to host `to`."
  @callback message_delay(from :: host(), to :: Tartarus.host()) :: non_neg_integer()

  @key {__MODULE__, :module}

  @doc "Installs `module` as this node's transport (it replaces any other)."
  @spec install(module()) :: :ok
  def install(module) when is_atom(module) do
    # A :persistent_term write is costly (every process is scanned): only when it changes.
    if installed() != module, do: :persistent_term.put(@key, module)
    :ok
  end

  @doc "Removes this node's transport."
  @spec clear() :: :ok
  def clear do
    _ = :persistent_term.erase(@key)
    :ok
  end

  @doc "This node's transport, or nil."
  @spec installed() :: module() | nil
  def installed, do: :persistent_term.get(@key, nil)

  @doc """
  The one-way delay, in ms, of a message from host `from` (as a transport is given it) to
  host `to`: the installed transport's `c:message_delay/2`, or 0 when none is installed.
  Every message between hosts that the platform sends (an agent's message, a signal relay,
  a broadcast) pays it.
  """
  @spec delay(host() | nil, Tartarus.host()) :: non_neg_integer()
  def delay(nil, _to), do: 0
  def delay(%{ref: to}, to), do: 0

  def delay(from, to) do
    case installed() do
      nil -> 0
      transport -> transport.message_delay(from, to)
    end
  end

  @doc """
  The links of host `host` of this node, as `[{neighbour, props}]` (props as given to
  `Tartarus.connect/3`, a map); `[]` for a host that is not on this node. For transports
  that charge a message by its route.
  """
  @spec links_of(Tartarus.host()) :: [{Tartarus.host(), map()}]
  def links_of(host) do
    case Tartarus.Host.local(host) do
      {:ok, info} ->
        for n <- Tartarus.Ledger.neighbours(info), do: {n, Tartarus.Ledger.link(info, n) || %{}}

      _ ->
        []
    end
  rescue
    ArgumentError -> []
  end

  @doc """
  The properties of the link from `host` (as a transport is given it) to `dest`, as given
  to `Tartarus.connect/3` (a map), or nil when they are not linked.
  """
  @spec link(host(), Tartarus.host()) :: map() | nil
  def link(host, dest), do: Tartarus.Ledger.link(host, dest)
end
