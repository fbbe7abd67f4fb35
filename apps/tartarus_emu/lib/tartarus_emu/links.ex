defmodule TartarusEmu.Links do
  @moduledoc """
  The emulator's transport (`Tartarus.Transport`): the latency and loss of emulated links,
  read from the link properties the emulator gives `Tartarus.connect/3`.

    * A hand-off over a link with `latency_ms: L` waits `3 * L` ms in the source before it
      sends `prepare` (its three messages: prepare, prepared, commit; the modules' round trip
      of a first crossing is not charged); with `loss: p` it fails with `:link_loss` with
      probability `p`, drawn from the agent's own random stream (runs are reproducible).
    * A message from an agent to an agent on a neighbouring host waits `L` ms each way.
    * Hosts that are not neighbours, and a host and itself, cost nothing.

  `TartarusEmu.Network` installs it (`install/1`) on the nodes of the hosts it links with a
  latency or a loss; install it yourself to emulate links made with `Tartarus.connect/3`
  directly.
  """

  @behaviour Tartarus.Transport

  @doc "Installs this transport on `nodes` (default: this node)."
  @spec install([node()]) :: :ok
  def install(nodes \\ [node()]) do
    Enum.each(Enum.uniq(nodes), fn
      n when n == node() -> Tartarus.Transport.install(__MODULE__)
      n -> :ok = :erpc.call(n, Tartarus.Transport, :install, [__MODULE__], 15_000)
    end)
  end

  @doc "True for link properties this transport acts on (a latency or a loss)."
  @spec emulated?(map() | keyword()) :: boolean()
  def emulated?(props) do
    props = Map.new(props)
    Map.get(props, :latency_ms, 0) > 0 or Map.get(props, :loss, 0) > 0
  end

  @impl true
  def hand_off(host, dest, rng) do
    case Tartarus.Transport.link(host, dest) do
      %{} = props ->
        latency = Map.get(props, :latency_ms, 0)
        if latency > 0, do: Process.sleep(3 * latency)
        loss = Map.get(props, :loss, 0)

        if loss > 0 do
          {x, state} = :rand.uniform_s(:rand.seed_s(rng))
          rng = :rand.export_seed_s(state)
          if x < loss, do: {:error, :link_loss, rng}, else: {:ok, rng}
        else
          {:ok, rng}
        end

      nil ->
        {:ok, rng}
    end
  end

  @impl true
  def message_delay(%{ref: host}, host), do: 0

  def message_delay(from, host) do
    case Tartarus.Transport.link(from, host) do
      %{latency_ms: ms} -> ms
      _ -> 0
    end
  end
end
