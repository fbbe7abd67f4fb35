defmodule TartarusWarehouse do
  @moduledoc """
  The warehouse of the thesis's chapter 4: mutual exclusion of shared resources by
  ordering robot tasks into a clock-less pipeline of mobile agents.

  Each task's program travels inside one mobile agent, which is also the token for the
  task's resources; a robot can only execute a task while that agent sits on it, so robots
  line up into a pipeline whose stages stretch and shrink with real execution times.

  | module | what it is |
  |---|---|
  | `TartarusWarehouse.Job` | the model (§4.3): job specs, their validation, their plan (cases A, B, C) |
  | `TartarusWarehouse.Distributor` | the Job Distributor (Algorithm 2), pure |
  | `TartarusWarehouse.DistributorAgent` | its process: a static agent on the distributor's host |
  | `TartarusWarehouse.TaskAgent` | task agents (Algorithm 3) |
  | `TartarusWarehouse.Robot` | the robot plugin: state, reach, program execution, history |
  | `TartarusWarehouse.Program` | task programs (shipped as code) |
  | `TartarusWarehouse.Central` | the centralized baseline (§4.7.2) |
  | `TartarusWarehouse.Floor` | a floor on the emulator, one process: `start/1` (a floor you drive from iex), `run/1` (a batch: start, submit, await, stop) |
  | `TartarusWarehouse.Panel` | the warehouse on the web dashboard |
  | `TartarusWarehouse.Checker` | Eq. 4.1 (mutual exclusion), completion, Eq. 4.2 (occupancy) over the history |
  | `TartarusWarehouse.Experiment` | the experiments of `mix tartarus.warehouse` (one module each, `TartarusWarehouse.Experiment.Robots`, ...; `experiments/0` is the registry) |
  """

  @doc """
  Validates and plans a job for `world` (see `TartarusWarehouse.Job.plan/2`).

      iex> world = TartarusWarehouse.Job.world([:a, :b], 2)
      iex> {:ok, plan} = TartarusWarehouse.plan(%{id: 1, tasks: [%{name: "T1", resources: [:a]}, %{name: "T2", resources: [:b]}]}, world)
      iex> plan.case
      :b
  """
  @spec plan(map(), TartarusWarehouse.Job.world()) ::
          {:ok, TartarusWarehouse.Job.plan()} | {:error, String.t()}
  defdelegate plan(spec, world), to: TartarusWarehouse.Job

  @doc "Runs jobs on an emulated floor. See `TartarusWarehouse.Floor.run/1`."
  @spec run(keyword()) :: {:ok, map()} | {:error, String.t()}
  defdelegate run(opts), to: TartarusWarehouse.Floor

  @doc """
  Starts a floor you drive (from iex): `submit/2` jobs, `change/2` it, `status/1`,
  `await/2`, `stop/1`. See `TartarusWarehouse.Floor.start/1`.
  """
  @spec start(keyword()) :: {:ok, pid()} | {:error, String.t()}
  defdelegate start(opts \\ []), to: TartarusWarehouse.Floor

  @doc "Submits a job to a started floor. See `TartarusWarehouse.Floor.submit/2`."
  @spec submit(pid(), map()) :: :ok | {:error, String.t()}
  defdelegate submit(floor, job), to: TartarusWarehouse.Floor

  @doc "Changes a started floor while it runs. See `TartarusWarehouse.Floor.change/2`."
  @spec change(pid(), term()) :: :ok | {:error, String.t()}
  defdelegate change(floor, event), to: TartarusWarehouse.Floor

  @doc "What a started floor is doing. See `TartarusWarehouse.Floor.status/1`."
  @spec status(pid()) :: map()
  defdelegate status(floor), to: TartarusWarehouse.Floor

  @doc "Waits for a started floor's jobs. See `TartarusWarehouse.Floor.await/2`."
  @spec await(pid(), timeout()) :: :ok | {:error, :timeout | :stopped | String.t()}
  defdelegate await(floor, timeout \\ 60_000), to: TartarusWarehouse.Floor

  @doc "Stops a started floor; returns what ran. See `TartarusWarehouse.Floor.stop/1`."
  @spec stop(pid()) :: {:ok, map()}
  defdelegate stop(floor), to: TartarusWarehouse.Floor
end
