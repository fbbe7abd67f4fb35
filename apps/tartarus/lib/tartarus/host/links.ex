defmodule Tartarus.Host.Links do
  @moduledoc false
  # The overlay's links: `connect/3` records a symmetric link at both ends (both must
  # exist first), `disconnect/2` removes it. Each end is asked on its own node
  # (`Tartarus.Host.OnNode.link/2`), so a host can take overlay changes only from there.

  alias Tartarus.Host

  @doc false
  @spec connect(Host.name() | Host.t(), Host.name() | Host.t(), keyword()) ::
          :ok | {:error, term()}
  def connect(a, b, props) do
    with {:ok, props} <- Tartarus.Options.Platform.link(props) do
      props = Map.new(props)
      a = Host.address(a)
      b = Host.address(b)

      # Both ends must exist before either records the link.
      with {:ok, _} <- Host.whereis(a),
           {:ok, _} <- Host.whereis(b),
           :ok <- Host.OnNode.run(a, :link, [{:connect, b, props}]),
           :ok <- Host.OnNode.run(b, :link, [{:connect, a, props}]) do
        :ok
      end
    end
  end

  @doc false
  @spec disconnect(Host.name() | Host.t(), Host.name() | Host.t()) :: :ok | {:error, term()}
  def disconnect(a, b) do
    a = Host.address(a)
    b = Host.address(b)
    r1 = Host.OnNode.run(a, :link, [{:disconnect, b}])
    r2 = Host.OnNode.run(b, :link, [{:disconnect, a}])
    if r1 == :ok or r2 == :ok, do: :ok, else: r1
  end
end
