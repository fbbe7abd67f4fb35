defmodule TartarusImmune.Evolution.Objective do
  @moduledoc """
  The objective functions of the three scenarios of thesis §7.3.1 (Eqs. 7.1-7.3), summed
  over an evaluation period, on a trace of samples (one per time step). Each sample is a map
  of normalized values (all in `[0, 1]`):

    * `:v_trans` - translational speed, absolute, normalized by the top speed
      (`TartarusArena.World.motion/2`);
    * `:v_rot` - rotational speed (absolute, normalized);
    * `:d` - the ultrasonic distance to the obstacle ahead (1: nothing in range);
    * `:light` - the two light sensors, `[l1, l2]` (1: brightest);
    * `:puck` - a puck is in the gripper (`b_puck`, boolean);
    * `:light_on` - the light is on (`b_light`, boolean; S3 only).

  The terms:

    * `f_obs = v_trans * (1 - v_rot) * d` (Eq. 7.1, after Nolfi and Floreano);
    * `f_light = max(l1, l2)`;
    * `f_puck = b_puck + v_trans` (Eq. 7.2 as printed: holding a puck, and moving);
    * `f_antipuck = (1 - b_puck) * v_trans` - the thesis says only that it "models the
      repulsion of a robot when it encounters a puck"; we reward moving on without a puck
      in the gripper (our choice);
    * S3 (Eq. 7.3): `f_obs + f_light + b_light * f_puck + (1 - b_light) * f_antipuck`.

      iex> alias TartarusImmune.Evolution.Objective
      iex> s = %{v_trans: 1.0, v_rot: 0.0, d: 1.0, light: [0.2, 0.5], puck: false}
      iex> Objective.fitness(:s1, [s, s])
      3.0
  """

  @typedoc "One time step's normalized readings."
  @type sample :: %{
          required(:v_trans) => number(),
          required(:v_rot) => number(),
          required(:d) => number(),
          required(:light) => [number()],
          optional(:puck) => boolean(),
          optional(:light_on) => boolean()
        }

  @doc "The sum over `trace` of the scenario's per-step objective (`:s1`, `:s2`, `:s3`)."
  @spec fitness(:s1 | :s2 | :s3, [sample()]) :: float()
  def fitness(scenario, trace), do: Enum.reduce(trace, 0.0, &(step(scenario, &1) + &2))

  @doc """
  One step's objective.

      iex> alias TartarusImmune.Evolution.Objective
      iex> Objective.step(:s2, %{v_trans: 0.5, v_rot: 0.5, d: 0.4, light: [0.3, 0.1], puck: true})
      1.9
      iex> Objective.step(:s3, %{v_trans: 0.5, v_rot: 0.0, d: 1.0, light: [0.0, 0.0], puck: true, light_on: false})
      0.5
  """
  @spec step(:s1 | :s2 | :s3, sample()) :: float()
  def step(:s1, s), do: f_obs(s) + f_light(s)
  def step(:s2, s), do: f_obs(s) + f_light(s) + f_puck(s)

  def step(:s3, s) do
    on = if Map.get(s, :light_on, false), do: 1, else: 0
    f_obs(s) + f_light(s) + on * f_puck(s) + (1 - on) * f_antipuck(s)
  end

  @doc "`v_trans * (1 - v_rot) * d`: fast, straight, away from obstacles."
  @spec f_obs(sample()) :: float()
  def f_obs(s), do: s.v_trans * (1 - s.v_rot) * s.d * 1.0

  @doc "The brighter of the two light sensors."
  @spec f_light(sample()) :: float()
  def f_light(s), do: Enum.max(s.light) * 1.0

  @doc "`b_puck + v_trans`."
  @spec f_puck(sample()) :: float()
  def f_puck(s), do: b(Map.get(s, :puck, false)) + s.v_trans * 1.0

  @doc "`(1 - b_puck) * v_trans`."
  @spec f_antipuck(sample()) :: float()
  def f_antipuck(s), do: (1 - b(Map.get(s, :puck, false))) * s.v_trans * 1.0

  defp b(true), do: 1.0
  defp b(_), do: 0.0
end
