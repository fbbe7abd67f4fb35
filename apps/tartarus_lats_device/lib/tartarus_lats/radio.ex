defmodule TartarusLats.Radio do
  @moduledoc """
  A simulated BLE radio channel: what RSSI a node reports for a tag at a distance.

  The model is the log-distance path loss with Gaussian shadowing,

      rssi(d) = tx_power - 10 * exponent * log10(max(d, 0.1)) - extra_loss + N(0, sigma)

  plus the two imperfections the thesis shows in Figure 3.7:

    * **spikes** - with probability `:spike_probability` a reading is
      boosted by a uniform `:spike_db` range (reflections), which can make a
      distant tag briefly look far or even near;
    * **drops** - with probability `:drop_probability` a packet is lost.

  A reading below the receiver's `:sensitivity` is not heard. Heard
  readings are rounded to integer dBm (as an HM-10 reports them); unheard
  ones are `:missing`.

  All randomness goes through an explicit `:rand` state (`t:rng/0`), never
  the process dictionary, so a simulation is reproducible from its seed:

      iex> rng = TartarusLats.Radio.seed(42)
      iex> radio = TartarusLats.Radio.new()
      iex> {r1, _} = TartarusLats.Radio.sample(radio, 3.0, -59, rng)
      iex> {r2, _} = TartarusLats.Radio.sample(radio, 3.0, -59, rng)
      iex> r1 == r2
      true
      iex> {r, _} = TartarusLats.Radio.sample(radio, 80.0, -59, rng)
      iex> r
      :missing
  """

  defstruct exponent: 2.0,
            noise_sigma: 2.0,
            spike_probability: 0.01,
            spike_db: {10, 25},
            drop_probability: 0.02,
            sensitivity: -90

  @typedoc "An explicit `:rand` state."
  @type rng :: :rand.state()

  @type t :: %__MODULE__{
          exponent: number(),
          noise_sigma: number(),
          spike_probability: number(),
          spike_db: {number(), number()},
          drop_probability: number(),
          sensitivity: number()
        }

  @doc """
  A radio model. Options and defaults: `exponent: 2.0`, `noise_sigma: 2.0`
  (dB), `spike_probability: 0.01`, `spike_db: {10, 25}`,
  `drop_probability: 0.02`, `sensitivity: -90` (dBm).

      iex> TartarusLats.Radio.new(noise_sigma: -1)
      ** (ArgumentError) invalid options given to TartarusLats.Radio.new/1 for key :noise_sigma: expected a non-negative number, got: -1
  """
  @spec new(keyword()) :: t()
  def new(opts \\ []) do
    alias TartarusLats.Options

    schema = [
      exponent: [type: :any, check: :positive, doc: "path-loss exponent"],
      noise_sigma: [type: :any, check: :non_negative, doc: "noise (dB)"],
      spike_probability: [type: :any, check: :probability, doc: "spikes"],
      spike_db: [type: :any, check: :db_range, doc: "spike size"],
      drop_probability: [type: :any, check: :probability, doc: "drops"],
      sensitivity: [type: :number, doc: "weakest RSSI heard (dBm)"]
    ]

    opts = Options.validate!(opts, schema, "TartarusLats.Radio.new/1")
    struct!(__MODULE__, opts)
  end

  @doc """
  A fresh `:rand` state (algorithm `exsss`) from an integer seed.
  """
  @spec seed(integer()) :: rng()
  def seed(seed) when is_integer(seed), do: :rand.seed_s(:exsss, seed)

  @doc """
  The noiseless mean RSSI at `distance_m` (distances under 0.1 m count as 0.1 m).

      iex> TartarusLats.Radio.mean_rssi(1.0, -59, 2.0)
      -59.0
      iex> TartarusLats.Radio.mean_rssi(10.0, -59, 2.0)
      -79.0
  """
  @spec mean_rssi(number(), number(), number()) :: float()
  def mean_rssi(distance_m, tx_power, exponent) do
    tx_power - 10 * exponent * :math.log10(max(distance_m, 0.1))
  end

  @doc """
  Mean RSSI plus Gaussian noise of standard deviation `noise_sigma` (no spikes,
  drops, rounding or sensitivity): the bare log-distance model.

      iex> {v, _rng} = TartarusLats.Radio.rssi(1.0, -59, 2.0, 0.0, TartarusLats.Radio.seed(1))
      iex> v
      -59.0
  """
  @spec rssi(number(), number(), number(), number(), rng()) :: {float(), rng()}
  def rssi(distance_m, tx_power, exponent, noise_sigma, rng) do
    {z, rng} = :rand.normal_s(rng)
    {mean_rssi(distance_m, tx_power, exponent) + noise_sigma * z, rng}
  end

  @doc """
  One reading as a receiver would report it: integer dBm or `:missing`.

  `extra_loss_db` is added attenuation (walls, floors), default 0.
  """
  @spec sample(t(), number(), number(), rng(), number()) :: {integer() | :missing, rng()}
  def sample(%__MODULE__{} = radio, distance_m, tx_power, rng, extra_loss_db \\ 0) do
    {value, rng} = rssi(distance_m, tx_power, radio.exponent, radio.noise_sigma, rng)
    {u_spike, rng} = :rand.uniform_s(rng)
    {u_drop, rng} = :rand.uniform_s(rng)
    {u_size, rng} = :rand.uniform_s(rng)
    {lo, hi} = radio.spike_db
    spike = if u_spike < radio.spike_probability, do: lo + (hi - lo) * u_size, else: 0
    value = value - extra_loss_db + spike

    cond do
      u_drop < radio.drop_probability -> {:missing, rng}
      value < radio.sensitivity -> {:missing, rng}
      true -> {round(value), rng}
    end
  end
end
