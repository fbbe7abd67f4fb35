defmodule TartarusImmune.Evolution.NeuralNet do
  @moduledoc """
  Small feed-forward networks whose weights are one flat vector (what the (1+1)-online
  strategy mutates and what agents carry): the 4-5-2 sub-controller of thesis §7.3 and the
  2-3-1 network of the OR-gate sharing experiment (§7.4.3).

  A shape is a list of layer sizes, `[4, 5, 2]`. Every neuron of a layer after the first has
  one weight per neuron of the layer before plus a bias, and applies `tanh`. The flat vector
  lists, layer by layer, each neuron's weights followed by its bias:

      [w(h1,i1), w(h1,i2), ..., b(h1), w(h2,i1), ..., b(h2), ..., w(o1,h1), ..., b(o1), ...]

  so a 4-5-2 network has 5 x (4 + 1) + 2 x (5 + 1) = 37 weights and a 2-3-1 network 13.
  Inputs are expected in `[0, 1]` (normalized sensor values), outputs are in `(-1, 1)`.
  """

  @typedoc "Layer sizes, inputs first."
  @type shape :: [pos_integer()]

  @typedoc "The flat weight vector."
  @type weights :: [float()]

  @doc """
  The number of weights (with biases) of a shape.

      iex> TartarusImmune.Evolution.NeuralNet.size([4, 5, 2])
      37
      iex> TartarusImmune.Evolution.NeuralNet.size([2, 3, 1])
      13
  """
  @spec size(shape()) :: pos_integer()
  def size(shape) do
    shape
    |> Enum.chunk_every(2, 1, :discard)
    |> Enum.map(fn [a, b] -> (a + 1) * b end)
    |> Enum.sum()
  end

  @doc """
  Random weights, uniform in `[-range, range]` (default 1.0), drawn from the `:rand`
  state `rng`. Returns `{weights, rng}`.
  """
  @spec random(shape(), :rand.state(), number()) :: {weights(), :rand.state()}
  def random(shape, rng, range \\ 1.0) do
    Enum.map_reduce(1..size(shape), rng, fn _, rng ->
      {u, rng} = :rand.uniform_s(rng)
      {(2 * u - 1) * range, rng}
    end)
  end

  @doc """
  The network's outputs for one input vector.

  A 1-1 network with weight 0.5 and bias 0 gives `tanh(0.5 x)`:

      iex> [y] = TartarusImmune.Evolution.NeuralNet.forward([1, 1], [0.5, 0.0], [1.0])
      iex> Float.round(y, 6)
      0.462117

  Raises `ArgumentError` when the weights or inputs do not fit the shape.
  """
  @spec forward(shape(), weights(), [number()]) :: [float()]
  def forward([n_in | _] = shape, weights, inputs) do
    if length(weights) != size(shape),
      do:
        raise(
          ArgumentError,
          "expected #{size(shape)} weights for #{inspect(shape)}, got #{length(weights)}"
        )

    if length(inputs) != n_in,
      do:
        raise(
          ArgumentError,
          "expected #{n_in} inputs for #{inspect(shape)}, got #{length(inputs)}"
        )

    {out, []} =
      shape
      |> tl()
      |> Enum.reduce({inputs, weights}, fn n, {x, ws} -> layer(x, ws, n, length(x)) end)

    out
  end

  @doc """
  The outputs for many input vectors (one list of outputs per input vector).
  """
  @spec forward_batch(shape(), weights(), [[number()]]) :: [[float()]]
  def forward_batch(shape, weights, inputs), do: Enum.map(inputs, &forward(shape, weights, &1))

  defp layer(x, ws, n, k) do
    Enum.map_reduce(1..n, ws, fn _, ws ->
      {neuron, rest} = Enum.split(ws, k + 1)
      {w, [b]} = Enum.split(neuron, k)
      {:math.tanh(dot(w, x, 0.0) + b), rest}
    end)
  end

  defp dot([w | ws], [x | xs], acc), do: dot(ws, xs, acc + w * x)
  defp dot([], [], acc), do: acc
end
