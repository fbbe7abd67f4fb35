defmodule Tartarus.Host.Links do
  @moduledoc false
  # The overlay's links: `connect/3` records a symmetric link at both ends (both must
  # exist first), `disconnect/2` removes it.

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
           :ok <- Host.call(a, {:connect, b, props}),
           :ok <- Host.call(b, {:connect, a, props}) do
        :ok
      end
    end
  end

  @doc false
  @spec disconnect(Host.name() | Host.t(), Host.name() | Host.t()) :: :ok | {:error, term()}
  def disconnect(a, b) do
    a = Host.address(a)
    b = Host.address(b)
    r1 = Host.call(a, {:disconnect, b})
    r2 = Host.call(b, {:disconnect, a})
    if r1 == :ok or r2 == :ok, do: :ok, else: r1
  end
end
