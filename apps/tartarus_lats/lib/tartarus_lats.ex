defmodule TartarusLats do
  @moduledoc """
  LATS on Tartarus (thesis ch. 3): BLE location tracking where every node
  keeps its own data and queries travel as mobile agents.

  ## The parts

    * `TartarusLats.BeaconPlugin` - a node's BLE receiver, a `Tartarus.Plugin`
      (simulated; the HM-10/UART one comes with the firmware);
    * `TartarusLats.DatabaseAgent` - the static agent of each node (named
      `"lats-db"`): tracker, log (durable, DETS), motion vectors, handshake
      with the neighbours; publishes in the host store;
    * `TartarusLats.Query.WhereAmI`, `TartarusLats.Query.WhereIs`,
      `TartarusLats.Query.Trace` - the query agents; `TartarusLats.Query` - the
      decisions they make on each node (shared with the cloud);
    * `TartarusLats.Cloud` - the cloud: counts connections and bytes per design,
      and answers queries centrally in the centralized design;
    * `TartarusLats.Deployment` - a building (a `TartarusEmu.Topology`) brought
      to life by `TartarusEmu.Network` with LATS's per-node setup hook, driven
      one world second at a time; `TartarusLats.Experiment` - the thesis's
      comparison as a `TartarusEmu.Scenario` (`mix tartarus.lats`; its queries in
      `TartarusLats.Experiment.Queries`, its summary in
      `TartarusLats.Experiment.Summary`), judged by `TartarusLats.Judge` (is an
      answer true of the bearer in the lag window) and reported by
      `TartarusLats.Report`.

  ## Asking from iex

      dep = TartarusLats.Deployment.start(seed: 1) |> TartarusLats.Deployment.run(300)
      tag = TartarusLats.World.tag(dep.world, :janitor)
      TartarusLats.query(dep.hosts[:p1], :where_is, tag)
      #=> {:ok, %{answer: {:in_zone, :p16}, hops: 4, route: [...], ...}}
      TartarusLats.query(dep.hosts[:p1], :trace, tag)

  Many queries may run at once: each is its own agent.

  ## Writing a new query at run time

  A query is an ordinary mobile agent: define a module that `use`s
  `Tartarus.Agent` in iex (it is registered with the code cache and ships
  to any node it moves to), read the LATS entries of the host store on each
  node (see `TartarusLats.DatabaseAgent`), and return the answer. For
  example, "which tags has the node I am on ever seen, around the building":

      defmodule Census do
        use Tartarus.Agent

        def init(n), do: visit(%{left: n, seen: %{}})
        def handle_arrival(_ctx, s), do: visit(s)

        defp visit(s) do
          mv = Tartarus.Agent.store_get({:lats, :mv})
          node = Tartarus.Agent.store_get({:lats, :node})
          s = %{s | seen: Map.put(s.seen, node, TartarusLats.MotionVectors.tags(mv))}
          if s.left == 0, do: {:return, s.seen, s}, else: {:move, :conscientious, %{s | left: s.left - 1}}
        end
      end

      TartarusLats.query(dep.hosts[:p3], Census, 10)

  `query/4` takes the three built-in types by name or any agent module.
  """

  alias Tartarus.Clock
  alias TartarusLats.Query

  require Tartarus.Clock

  @typedoc "A query type, or an agent module."
  @type query_type :: :where_am_i | :where_is | :trace | module()

  @doc """
  Releases a query agent on `host` and waits for its answer.

  For the built-in types `arg` is the tag (`{uuid, major, minor}`); for an
  agent module it is that module's `init/1` argument. Options: `:timeout`
  (ms, default 60 000), `:label` and `:report` (passed to built-in query
  agents: a label for the cloud log; whether to contact the cloud, default
  true), `:cloud` (`:per_node`, the default: the agent contacts the cloud
  from every node where it finds data of the tag, as in the thesis's
  scenario 2; `:per_query`: once, from where it found the answer), `:seed`
  (the agent's random seed, for reproducible walks), `:repair` (Where is X and Trace:
  bridge a broken chain by asking the nodes around the gap, see
  `TartarusLats.Query.WhereIs` and `TartarusLats.Query.Trace`; default false).

  Returns `{:ok, result}` where `result` is what the agent returned (for
  the built-in queries a map with `:answer`, `:hops`, `:route`,
  `:answered_at`, `:cloud_contacts`, `:per_node_contacts`,
  `:per_query_contacts`, `:elapsed_us`), or `{:error, reason}`.
  `:elapsed_us` is the answering node's `Tartarus.Clock.monotonic_time/1` minus the
  starting node's: meaningful only when both run in one VM. `TartarusLats.Experiment`
  measures latency in the releasing process instead (one clock).
  """
  @spec query(Tartarus.host_ref(), query_type(), term(), keyword()) ::
          {:ok, term()} | {:error, term()}
  def query(host, type, arg, opts \\ []) do
    with {:ok, id} <- release(host, type, arg, opts) do
      await(id, Keyword.get(opts, :timeout, 60_000))
    end
  end

  @doc """
  Releases a query agent without waiting; the caller receives
  `{:tartarus_result, id, result}`. See `query/4`. Returns `{:ok, id}`.
  """
  @spec release(Tartarus.host_ref(), query_type(), term(), keyword()) ::
          {:ok, Tartarus.agent_id()} | {:error, term()}
  def release(host, type, arg, opts \\ []) do
    {module, args} =
      case type do
        :where_am_i -> {Query.WhereAmI, builtin_args(arg, opts)}
        :where_is -> {Query.WhereIs, builtin_args(arg, opts)}
        :trace -> {Query.Trace, builtin_args(arg, opts)}
        module when is_atom(module) -> {module, arg}
      end

    create_opts = [owner: self()] ++ Keyword.take(opts, [:seed])
    Tartarus.create_mobile_agent(host, module, args, create_opts)
  end

  @doc "Waits for the result of a released query agent."
  @spec await(Tartarus.agent_id(), timeout()) :: {:ok, term()} | {:error, term()}
  def await(id, timeout \\ 60_000) do
    Clock.receive do
      {:tartarus_result, ^id, result} -> {:ok, result}
      {:tartarus_removed, ^id, reason} -> {:error, {:removed, reason}}
    after
      timeout -> {:error, :timeout}
    end
  end

  defp builtin_args(tag, opts) do
    %{
      tag: tag,
      label: Keyword.get(opts, :label),
      report: Keyword.get(opts, :report, true),
      cloud: Keyword.get(opts, :cloud, :per_node),
      repair: Keyword.get(opts, :repair, false)
    }
  end
end
