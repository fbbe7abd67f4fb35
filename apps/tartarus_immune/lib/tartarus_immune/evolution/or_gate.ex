defmodule TartarusImmune.Evolution.OrGate do
  @moduledoc """
  The soft task of the sharing experiment (thesis §7.4.3): a 2-3-1 network
  (`TartarusImmune.Evolution.NeuralNet`) learning the OR function.

  The network's `tanh` output `y` is read as `(y + 1) / 2`, in `(0, 1)`. **Fitness** is
  `1 - MSE` over the four cases (in `[0, 1]`, higher is better). A controller **solves** the
  task when each of the four outputs is within `0.2` of its target (`solved?/1`): that is
  "the best solution" of §7.4.3, whose spread through the network the convergence count
  measures.

      iex> alias TartarusImmune.Evolution.OrGate
      iex> # hidden h1 = tanh(4 a + 4 b - 2); output = tanh(4 h1 + 1)
      iex> w = [4.0, 4.0, -2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 4.0, 0.0, 0.0, 1.0]
      iex> OrGate.solved?(w)
      true
      iex> OrGate.fitness(w) > 0.95
      true
      iex> OrGate.solved?(List.duplicate(0.0, 13))
      false
  """

  alias TartarusImmune.Evolution.NeuralNet

  @shape [2, 3, 1]
  @cases [{[0, 0], 0}, {[0, 1], 1}, {[1, 0], 1}, {[1, 1], 1}]
  @tolerance 0.2

  @doc "The network shape, `[2, 3, 1]`."
  @spec shape() :: NeuralNet.shape()
  def shape, do: @shape

  @doc "The outputs, in `(0, 1)`, for the four cases `00, 01, 10, 11`."
  @spec outputs([float()]) :: [float()]
  def outputs(weights) do
    for {x, _} <- @cases, do: (hd(NeuralNet.forward(@shape, weights, x)) + 1) / 2
  end

  @doc "`1 - MSE` over the four cases."
  @spec fitness([float()]) :: float()
  def fitness(weights) do
    errors =
      weights
      |> outputs()
      |> Enum.zip(@cases)
      |> Enum.map(fn {y, {_, t}} -> (y - t) * (y - t) end)

    1 - Enum.sum(errors) / 4
  end

  @doc "Whether every output is within 0.2 of its target."
  @spec solved?([float()]) :: boolean()
  def solved?(weights) do
    weights
    |> outputs()
    |> Enum.zip(@cases)
    |> Enum.all?(fn {y, {_, t}} -> abs(y - t) < @tolerance end)
  end
end
