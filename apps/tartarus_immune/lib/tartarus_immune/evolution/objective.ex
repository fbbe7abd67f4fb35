defmodule TartarusImmune.Evolution.Objective do
  @moduledoc """
  The objective functions of the three scenarios of thesis §7.3.1 (Eqs. 7.1-7.3), summed
  over an evaluation period, on a trace of samples (one per time step). Each sample is a map
  of normalized values (all in `[0, 1]`):

    * `:v_trans` - forward translational speed, normalized by the top speed, 0 when
      backing up (`TartarusImmune.Evolution.Embodied.sample/3` says why);
    * `:v_rot` - rotational speed (absolute, normalized);
    * `:d` - the ultrasonic distance to the obstacle ahead (1: nothing in range);
    * `:light` - the two light sensors, `[l1, l2]` (1: brightest);
    * `:puck` - a puck is in the gripper (`b_puck`, boolean): on the arena, the colour
      sensor behind the pusher reads yellow (`TartarusImmune.Evolution.Embodied.sample/3`);
    * `:light_on` - the light is on (`b_light`, boolean; S3 only).

  The terms:

    * `f_obs = v_trans * (1 - v_rot) * d` (Eq. 7.1, after Nolfi and Floreano);
    * `f_light = max(l1, l2)`;
    * `f_puck`, "a function which rewards puck pushing behavior" (the thesis's list of
      symbols), in one of two readings chosen by the option `puck_reward`:
      * `:product` (default) - `b_puck * v_trans`: moving with a puck in the gripper, which
        is what pushing a puck is;
      * `:sum` - `b_puck + v_trans`, Eq. 7.2 as printed: holding a puck, plus moving
        anywhere, with or without a puck;
    * `f_antipuck = (1 - b_puck) * v_trans` - the thesis says only that it "models the
      repulsion of a robot when it encounters a puck"; we reward moving on without a puck
      in the gripper (our choice, the mirror of the product reading of `f_puck`);
    * S3 (Eq. 7.3): `f_obs + f_light + b_light * f_puck + (1 - b_light) * f_antipuck`.

  Why the product is the default: the thesis names `f_puck` the reward of "puck pushing
  behavior" and, in the text of S2, of "the controlled pushing of the puck using the
  gripper". Pushing is moving *with* a puck, a conjunction, which is a product of the
  binary `b_puck` and the speed (Eq. 7.1 writes its products with `*` in the same way).
  The sum rewards speed whether or not there is a puck: its `v_trans` term pays a robot
  that never meets a puck as much as one that pushes, and `f_obs` already rewards speed, so
  under the sum a robot gains more from driving fast anywhere than from pushing. The sum
  also does not mirror `f_antipuck`, which Eq. 7.3 uses as the reversal of `f_puck`
  when the light is off. We read the printed `+` as a misprint for `*`, and keep the
  printed sum as an option. Neither reading says where the puck should go: measured on the
  arena, under both a hand-made controller that takes pucks to the light scores above
  circling anywhere, but about as high as one that circles round the light whatever the
  pucks, and evolution finds controllers that score higher still and push no puck to the
  light (docs/evolution.md, "Why learning was weak").

      iex> alias TartarusImmune.Evolution.Objective
      iex> s = %{v_trans: 1.0, v_rot: 0.0, d: 1.0, light: [0.2, 0.5], puck: false}
      iex> Objective.fitness(:s1, [s, s])
      3.0
      iex> p = %{s | puck: true, v_trans: 0.5}
      iex> {Objective.f_puck(p), Objective.f_puck(p, :sum), Objective.f_puck(s), Objective.f_puck(s, :sum)}
      {0.5, 1.5, 0.0, 1.0}
  """

  @typedoc "The reading of `f_puck`: `b_puck * v_trans` (default) or `b_puck + v_trans`."
  @type puck_reward :: :product | :sum

  @typedoc "One time step's normalized readings."
  @type sample :: %{
          required(:v_trans) => number(),
          required(:v_rot) => number(),
          required(:d) => number(),
          required(:light) => [number()],
          optional(:puck) => boolean(),
          optional(:light_on) => boolean()
        }

  @doc """
  The sum over `trace` of the scenario's per-step objective (`:s1`, `:s2`, `:s3`). Option:
  `puck_reward` (`:product`, the default, or `:sum`; see the module doc).
  """
  @spec fitness(:s1 | :s2 | :s3, [sample()], keyword()) :: float()
  def fitness(scenario, trace, opts \\ []) do
    reading = puck_reward!(opts)
    Enum.reduce(trace, 0.0, &(step(scenario, &1, reading) + &2))
  end

  @doc """
  The `puck_reward` option of `opts` (default `:product`); raises `ArgumentError` naming
  the key, what is expected and what it got otherwise.

      iex> TartarusImmune.Evolution.Objective.puck_reward!(puck_reward: :sum)
      :sum
      iex> TartarusImmune.Evolution.Objective.puck_reward!([])
      :product
  """
  @spec puck_reward!(keyword()) :: puck_reward()
  def puck_reward!(opts) do
    case Keyword.get(opts, :puck_reward, :product) do
      r when r in [:product, :sum] ->
        r

      other ->
        raise ArgumentError,
              "invalid value for :puck_reward: expected :product or :sum, got: #{inspect(other)}"
    end
  end

  @doc """
  One step's objective, with `f_puck` read as `puck_reward` (`:product` by default).

      iex> alias TartarusImmune.Evolution.Objective
      iex> Objective.step(:s2, %{v_trans: 0.5, v_rot: 0.5, d: 0.4, light: [0.3, 0.1], puck: true})
      0.9
      iex> Objective.step(:s2, %{v_trans: 0.5, v_rot: 0.5, d: 0.4, light: [0.3, 0.1], puck: true}, :sum)
      1.9
      iex> Objective.step(:s3, %{v_trans: 0.5, v_rot: 0.0, d: 1.0, light: [0.0, 0.0], puck: true, light_on: false})
      0.5
  """
  @spec step(:s1 | :s2 | :s3, sample(), puck_reward()) :: float()
  def step(scenario, s, reading \\ :product)
  def step(:s1, s, _), do: f_obs(s) + f_light(s)
  def step(:s2, s, reading), do: f_obs(s) + f_light(s) + f_puck(s, reading)

  def step(:s3, s, reading) do
    on = if Map.get(s, :light_on, false), do: 1, else: 0
    f_obs(s) + f_light(s) + on * f_puck(s, reading) + (1 - on) * f_antipuck(s)
  end

  @doc "`v_trans * (1 - v_rot) * d`: fast, straight, away from obstacles."
  @spec f_obs(sample()) :: float()
  def f_obs(s), do: s.v_trans * (1 - s.v_rot) * s.d * 1.0

  @doc "The brighter of the two light sensors."
  @spec f_light(sample()) :: float()
  def f_light(s), do: Enum.max(s.light) * 1.0

  @doc "`b_puck * v_trans` (`:product`, the default) or `b_puck + v_trans` (`:sum`)."
  @spec f_puck(sample(), puck_reward()) :: float()
  def f_puck(s, reading \\ :product)
  def f_puck(s, :product), do: b(Map.get(s, :puck, false)) * s.v_trans * 1.0
  def f_puck(s, :sum), do: b(Map.get(s, :puck, false)) + s.v_trans * 1.0

  @doc "`(1 - b_puck) * v_trans`."
  @spec f_antipuck(sample()) :: float()
  def f_antipuck(s), do: (1 - b(Map.get(s, :puck, false))) * s.v_trans * 1.0

  defp b(true), do: 1.0
  defp b(_), do: 0.0
end
