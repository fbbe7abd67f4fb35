defmodule Tartarus.Agent do
  @moduledoc """
  The agent behaviour: static and mobile agents that live on hosts and migrate between them.

  ## Glossary

    * **agent** - a supervised process on a host running a module that `use`s this module.
      Its identity (id, name), state and payload travel; its stack does not (weak mobility).
    * **action** - what a callback returns; the platform carries it out.
    * **arrival** - an agent starting on a host after a migration (or a clone). It resumes in
      `c:handle_arrival/2`.

  ## Example

      defmodule Pinger do
        use Tartarus.Agent

        @impl true
        def init(laps), do: {:move, :conscientious, laps}

        @impl true
        def handle_arrival(_ctx, 0), do: {:return, Tartarus.Agent.hops(), 0}
        def handle_arrival(_ctx, laps), do: {:move, :conscientious, laps - 1}
      end

      {:ok, id} = Tartarus.create_mobile_agent(:a, Pinger, 10, owner: self())
      receive do
        {:tartarus_result, ^id, hops} -> hops
      end

  ## Actions

    * `{:stay, state}` - remain on this host and wait for messages;
    * `{:move, dest, state}` - migrate to `dest`: a host, or a strategy (`:random`,
      `:conscientious`, `{:gradient, signal}`, `{:strategy, module, arg}`; see
      `Tartarus.Strategy`);
    * `{:clone, dest, state}` - start a copy at `dest` (a host, a strategy, or `:here`); the
      copy gets a new id and name and starts in `c:handle_arrival/2` with `ctx.clone_of` set;
      the original keeps running here;
    * `{:return, result, state}` - deliver `result` to the owner as
      `{:tartarus_result, id, result}` and stop;
    * `{:stop, reason, state}` - stop (a normal exit: the agent is not restarted).

  ## What a move guarantees

  A move is a two-phase hand-off (DESIGN §6). If anything fails before the destination has
  the agent paused and ready (unknown or dead host, refused admission, code conflict, state
  that cannot travel, link loss, timeout), the agent stays here, running, and
  `c:handle_move_failed/4` decides what to do next. Once the source commits, the agent
  exists at the destination only. Messages sent to the agent while it moves are not lost:
  a sender whose message was not yet taken by the agent retries along the forwarding
  pointer the source leaves behind. Timers and links of the agent's process do not travel.

  State must be plain data: funs and ports cannot travel and make the move fail with
  `{:not_portable, :fun, path}`.

  ## Supervision

  Agents are watched by their host's server (not a supervisor's children: a hop or a create
  waits on no supervisor). A crashing agent is restarted from the snapshot taken when it
  arrived on the host (it re-runs `c:handle_arrival/2` with `ctx.restarts` counting
  restarts), at most `:max_restarts` times (a host option), then removed; its owner then
  receives `{:tartarus_removed, id, reason}`. An agent that overruns a callback's budget or
  is killed is not restarted. When its host stops, every agent on it is killed at once.

  An `c:init/1` that returns anything but an action fails the create
  (`{:error, {:init_failed, {:bad_action, returned}}}`). An agent's heap, mailbox included,
  is bounded by the host option `:max_heap_size` (64 MiB by default): past it the agent is
  killed and restarted as after a crash. Processes an agent starts with `spawn_link/1` end
  with it.

  ## Time budget

  Callbacks (`c:init/1` included) run in the agent's own process, never in its host's: an
  agent that computes, sleeps or waits does not hold up its host, its other agents, or
  `Tartarus.kill/1`. Each callback may run for at most the host option `:callback_timeout`
  (10 s by default; `:infinity` switches the bound off). An agent whose callback overruns
  is stopped (its exit reason is `{:callback_timeout, callback, ms}`) and not restarted:

    * an `c:init/1` that overruns: `Tartarus.create_agent/4` returns
      `{:error, {:callback_timeout, :init, ms}}`;
    * any other callback (`c:handle_arrival/2` after a move or a clone, `c:handle_message/3`,
      `c:handle_move_failed/4`, `c:handle_info/2`): the agent is removed from its host and
      its owner receives `{:tartarus_removed, id, {:callback_timeout, callback, ms}}`; a
      request it was handling gets `{:error, {:callback_timeout, :handle_message, ms}}`
      from `Tartarus.request/3`.

  A callback that returns after its budget ran out counts as an overrun (its action is not
  carried out). An agent killed with `Tartarus.kill/1` stops at once unless it traps exits;
  then it stops as soon as it waits for its next message (its code cannot keep it alive), or
  is killed at the end of its callback's budget if it does not.

  ## Inside callbacks

  Callbacks run in the agent's process and may use the functions of this module: `id/0`,
  `name/0`, `host/0`, `hops/0`, `neighbours/0`, the payload functions, the host store and
  the host's plugins (`read/2`, `write/2`, `subscribe/1`), and `reply/2`; the agent's own
  random stream (`uniform/0`, `uniform/1`, `normal/0`, `normal/2`, `shuffle/1`,
  `random_seed/0`, `random/1`: see `Tartarus.Random`); signal fields (`signal/2`,
  `signals/1`, `gradient/1`, `emit_signal/3`, `watch_signal/1`: see `Tartarus.Signal`); and neighbour
  broadcasts (`broadcast/1`, `subscribe_broadcasts/0`: see `Tartarus.Broadcast`).

  ## Options of `use Tartarus.Agent`

    * `:ships` - other modules the agent needs wherever it goes (shipped with it, like its
      own module).

  Agent modules compiled while the application runs (typed in iex, or compiled by a test)
  are registered with `Tartarus.CodeCache`, so they ship to nodes that never had them.
  """

  alias Tartarus.Envelope

  @typedoc "An agent's state."
  @type state :: term()

  @typedoc "Where to go: a host or a migration strategy."
  @type dest :: Tartarus.host_ref() | Tartarus.Strategy.t()

  @typedoc "What a callback returns."
  @type action ::
          {:stay, state()}
          | {:move, dest(), state()}
          | {:clone, dest() | :here, state()}
          | {:return, term(), state()}
          | {:stop, term(), state()}

  @typedoc """
  What the platform tells an agent about its arrival: the host, where it came from, its hop
  count, the id of the agent it was cloned from (if it is a clone) and how many times it was
  restarted on this host.
  """
  @type ctx :: %{
          host: Tartarus.host(),
          from: Tartarus.host() | nil,
          hops: non_neg_integer(),
          clone_of: String.t() | nil,
          restarts: non_neg_integer()
        }

  @typedoc "Whom to reply to, or nil for a one-way post."
  @type from :: {pid(), reference()} | nil

  @doc "Starts the agent on the host where it is created; returns its first action."
  @callback init(args :: term()) :: action()

  @doc "The agent arrived on a host (after a move, as a clone, or after a restart)."
  @callback handle_arrival(ctx(), state()) :: action()

  @doc """
  A message posted to the agent (`from` is nil) or a request (`from` is set: answer with
  `reply/2`, from this callback or later, from wherever the agent is by then).
  """
  @callback handle_message(message :: term(), from(), state()) :: action()

  @doc "A move or clone to `dest` failed with `reason`; the agent is still here."
  @callback handle_move_failed(dest(), reason :: term(), ctx(), state()) :: action()

  @doc """
  Any other message to the agent's process (timers, plugin events, broadcasts the agent
  subscribed to).
  """
  @callback handle_info(message :: term(), state()) :: action()

  @optional_callbacks handle_info: 2

  @doc false
  defmacro __using__(opts) do
    ships = Keyword.get(opts, :ships, [])

    quote do
      @behaviour Tartarus.Agent
      @after_compile Tartarus.Agent

      @doc false
      def __tartarus_agent__(:ships), do: unquote(ships)

      @impl Tartarus.Agent
      def handle_arrival(_ctx, state), do: {:stay, state}

      @impl Tartarus.Agent
      def handle_message(_message, _from, state), do: {:stay, state}

      @impl Tartarus.Agent
      def handle_move_failed(_dest, _reason, _ctx, state), do: {:stay, state}

      defoverridable handle_arrival: 2, handle_message: 3, handle_move_failed: 4
    end
  end

  @doc false
  def __after_compile__(env, bytecode) do
    Tartarus.CodeCache.remember(env.module, bytecode)
  end

  @doc "True if `module` is an agent module."
  @spec agent_module?(module()) :: boolean()
  def agent_module?(module) when is_atom(module) do
    Code.ensure_loaded?(module) and function_exported?(module, :__tartarus_agent__, 1)
  end

  def agent_module?(_), do: false

  # -- inside callbacks ----------------------------------------------------------

  # The calling agent's context: the one process-dictionary key of an agent's process, set
  # only while one of its callbacks runs (run_callback/4) and read by the functions below,
  # which its code calls with no argument naming the agent. It holds
  # {host, envelope, checkpoint?, children?}: the host's map, the envelope the functions
  # read and change (payload, random stream), whether checkpoint/0 was called, whether
  # spawn_link/1 started a process. Nothing else of the platform keeps a key in an agent's
  # dictionary: its state machine's data holds the rest, the host's watchdog reads the
  # ledger (Tartarus.Agent.Callbacks).
  @ctx :"$tartarus_agent"

  @doc "The id of the calling agent."
  @spec id() :: String.t()
  def id, do: envelope().id

  @doc "The name of the calling agent."
  @spec name() :: String.t()
  def name, do: envelope().name

  @doc "The host the calling agent is on."
  @spec host() :: Tartarus.host()
  def host, do: host_info().ref

  @doc "How many migrations the calling agent has made."
  @spec hops() :: non_neg_integer()
  def hops, do: envelope().hops

  @doc "How many times the calling agent has visited each host."
  @spec visits() :: %{Tartarus.host() => pos_integer()}
  def visits, do: envelope().visits

  @doc "The neighbours of the calling agent's host."
  @spec neighbours() :: [Tartarus.host()]
  def neighbours, do: Tartarus.Ledger.neighbours(host_info())

  @doc "The calling agent's data payload."
  @spec payload() :: map()
  def payload, do: envelope().payload.data

  @doc "Adds (or replaces) `key` in the calling agent's payload; it travels with the agent."
  @spec put_payload(term(), term()) :: :ok
  def put_payload(key, value), do: update_payload(&Map.put(&1, key, value))

  @doc "Removes `key` from the calling agent's payload."
  @spec remove_payload(term()) :: :ok
  def remove_payload(key), do: update_payload(&Map.delete(&1, key))

  @doc """
  Sheds `key` from the payload to the host store: the value stays on this host (readable
  by other agents with `store_get/2`) and no longer travels. Returns `{:error, :not_found}`
  if the payload has no such key.
  """
  @spec shed_payload(term()) :: :ok | {:error, :not_found}
  def shed_payload(key) do
    case Map.fetch(payload(), key) do
      {:ok, value} ->
        store_put(key, value)
        remove_payload(key)

      :error ->
        {:error, :not_found}
    end
  end

  @doc "Copies `key` of the payload to the host store; the agent keeps it too."
  @spec copy_payload(term()) :: :ok | {:error, :not_found}
  def copy_payload(key) do
    case Map.fetch(payload(), key) do
      {:ok, value} -> store_put(key, value)
      :error -> {:error, :not_found}
    end
  end

  @doc "Adds `module` to the modules that travel with the calling agent."
  @spec add_module(module()) :: :ok
  def add_module(module) when is_atom(module) do
    env = envelope()

    put_envelope(%{
      env
      | payload: %{env.payload | modules: Enum.uniq([module | env.payload.modules])}
    })
  end

  @doc "Reads `key` from the store of the calling agent's host."
  @spec store_get(term(), term()) :: term()
  def store_get(key, default \\ nil) do
    case :ets.lookup(host_info().store, key) do
      [{_, v}] -> v
      [] -> default
    end
  end

  @doc "Writes `key` in the store of the calling agent's host."
  @spec store_put(term(), term()) :: :ok
  def store_put(key, value) do
    :ets.insert(host_info().store, {key, value})
    :ok
  end

  @doc """
  Reads from plugin `plugin` of the calling agent's host. Agents reach only the plugins of
  the host they are on. See `Tartarus.Plugin`.
  """
  @spec read(atom(), term()) :: {:ok, term()} | {:error, term()}
  def read(plugin, args \\ nil), do: Tartarus.Plugin.call(host(), plugin, {:read, args})

  @doc "Writes to (actuates) plugin `plugin` of the calling agent's host."
  @spec write(atom(), term()) :: :ok | {:error, term()}
  def write(plugin, args), do: Tartarus.Plugin.call(host(), plugin, {:write, args})

  @doc """
  Subscribes the calling agent to the events of plugin `plugin` on its host. Events arrive
  in `c:handle_info/2` as `{:plugin_event, plugin, event}`. The subscription ends when the
  agent leaves the host.
  """
  @spec subscribe(atom()) :: :ok | {:error, term()}
  def subscribe(plugin), do: Tartarus.Plugin.call(host(), plugin, {:subscribe, self()})

  @doc """
  What the calling agent's host can do, as its plugins describe it:
  `%{capability => [plugin names]}` (see `Tartarus.Plugin`, "Capabilities"). A foraging
  agent hops to a robot's host and asks.
  """
  @spec capabilities() :: %{atom() => [atom()]}
  def capabilities do
    {host_name, _node} = host()
    Tartarus.Plugin.capabilities(Tartarus.Plugin.list(host_name))
  end

  @doc """
  Asks for the calling agent's state to be made durable: once the callback that calls this
  returns, the state it returns (with the payload as the callback left it) is written to the
  host's journal (host option `:data_dir`) and becomes the snapshot a restart restores, after
  a crash of the agent or of its node. Without a journal the snapshot is kept in memory only
  (it survives a crash of the agent, not of the node).

  With the host option `durable: true` every handled message is checkpointed this way before
  its sender gets `:ok`; this function is for agents on other hosts, or for changes made in
  `c:handle_info/2` or `c:handle_arrival/2`.
  """
  @spec checkpoint() :: :ok
  def checkpoint do
    Process.put(@ctx, put_elem(context(), 2, true))
    :ok
  end

  @doc """
  Starts a process linked to the calling agent that ends with it (from a callback). Processes
  cannot migrate: whenever the agent's process ends (it moved on, stopped, returned, crashed,
  was killed or removed), this process is killed, even if it traps exits. A process the
  agent starts otherwise is its own: one linked with `Kernel.spawn_link/1` ends with the
  agent unless it traps exits (the agent's process never ends with reason `:normal`), an
  unlinked one outlives it.
  """
  @spec spawn_link((() -> any())) :: pid()
  def spawn_link(fun) when is_function(fun, 0) do
    {host, _env, _checkpoint?, _children?} = ctx = context()
    pid = Kernel.spawn_link(fun)
    Tartarus.Ledger.add_child(host, self(), pid)
    Process.put(@ctx, put_elem(ctx, 3, true))
    pid
  end

  @doc false
  # Kills the processes agent process `agent` started with spawn_link/1 (by the agent as it
  # ends, or by its host when it was killed).
  @spec end_children(map(), pid()) :: :ok
  def end_children(host, agent) do
    Enum.each(Tartarus.Ledger.take_children(host, agent), &Process.exit(&1, :kill))
  end

  @doc "Answers a request (see `c:handle_message/3`). Works from any host."
  @spec reply(from(), term()) :: :ok
  def reply(nil, _value), do: :ok

  def reply({pid, ref}, value) do
    send(pid, {ref, {:reply, value}})
    :ok
  end

  # -- the agent's random stream -----------------------------------------------------

  @doc """
  A float uniformly distributed in `[0.0, 1.0)`, drawn from the calling agent's random
  stream (see `Tartarus.Random`): the stream travels with the agent and only the agent
  advances it, so for one `seed:` the agent draws the same numbers wherever it goes.
  """
  @spec uniform() :: float()
  def uniform, do: draw(&Tartarus.Random.uniform/1)

  @doc "An integer uniformly distributed in `1..n`, from the calling agent's random stream."
  @spec uniform(pos_integer()) :: pos_integer()
  def uniform(n) when is_integer(n) and n > 0, do: draw(&Tartarus.Random.uniform(&1, n))

  @doc "A float from N(0, 1), from the calling agent's random stream."
  @spec normal() :: float()
  def normal, do: draw(&Tartarus.Random.normal/1)

  @doc "A float from N(`mean`, `sd`²), from the calling agent's random stream."
  @spec normal(number(), number()) :: float()
  def normal(mean, sd), do: draw(&Tartarus.Random.normal(&1, mean, sd))

  @doc "The elements of `enumerable` in an order drawn from the calling agent's random stream."
  @spec shuffle(Enumerable.t()) :: list()
  def shuffle(enumerable), do: draw(&Tartarus.Random.shuffle(&1, enumerable))

  @doc """
  An integer seed drawn from the calling agent's random stream, to seed a generator for
  a batch computation (e.g. `:rand.seed_s(:exsss, seed)` or `Tartarus.Random.new(seed)`),
  reproducibly.
  """
  @spec random_seed() :: pos_integer()
  def random_seed, do: draw(&Tartarus.Random.seed/1)

  @doc """
  Runs `fun` on the calling agent's random stream as a `:rand` state (`fun.(state)`
  returns `{value, state}`, like the `:rand.*_s` functions) and keeps the advanced stream.
  Returns the value.
  """
  @spec random((:rand.state() -> {value, :rand.state()})) :: value when value: term()
  def random(fun) when is_function(fun, 1), do: draw(&Tartarus.Random.with_state(&1, fun))

  defp draw(fun) do
    env = envelope()
    {value, rng} = fun.(env.rng || Tartarus.Random.new(env.id))
    put_envelope(%{env | rng: rng})
    value
  end

  # -- signals and broadcasts ------------------------------------------------------------

  @doc """
  The value of signal `name` on the calling agent's host now (0.0 if none reaches it).
  See `Tartarus.Signal` (options: `combine:`).
  """
  @spec signal(Tartarus.Signal.name(), keyword()) :: float()
  def signal(name, opts \\ []), do: Tartarus.Signal.local_value(host(), name, opts)

  @doc """
  The live contributions to signal `name` on the calling agent's host, strongest first:
  maps with `:source`, `:hops`, `:value` and `:data` (what the emitter attached).
  """
  @spec signals(Tartarus.Signal.name()) :: [map()]
  def signals(name), do: Tartarus.Signal.local_contributions(host(), name)

  @doc """
  The values of signal `name` at the neighbours of the calling agent's host, as the host
  knows them: `%{neighbour => value}` (what `{:gradient, name}` climbs).
  """
  @spec gradient(Tartarus.Signal.name()) :: %{Tartarus.host() => float()}
  def gradient(name), do: Tartarus.Signal.local_neighbour_values(host(), name, [])

  @doc """
  Emits signal `name` of strength `strength` from the calling agent's host (see
  `Tartarus.Signal.emit/4` for the options).
  """
  @spec emit_signal(Tartarus.Signal.name(), number(), keyword()) :: :ok | {:error, term()}
  def emit_signal(name, strength, opts \\ []),
    do: Tartarus.Signal.emit(host(), name, strength, opts)

  @doc """
  Watches signal `name` on the calling agent's host: the agent receives
  `{:tartarus_signal, host, name}` in `c:handle_info/2` each time the host takes a new
  contribution to it (see `Tartarus.Signal`, "Watching"), so it can wait for a field
  without polling. Watch first, then read the field. The watch ends when the agent leaves
  the host.
  """
  @spec watch_signal(Tartarus.Signal.name()) :: :ok | {:error, term()}
  def watch_signal(name), do: Tartarus.Signal.watch(host(), name, self())

  @doc """
  Sends `message` to every neighbour of the calling agent's host (see `Tartarus.Broadcast`).
  Returns the number of neighbours it went to.
  """
  @spec broadcast(term()) :: non_neg_integer() | {:error, term()}
  def broadcast(message) do
    case Tartarus.Envelope.portable?(message) do
      :ok -> Tartarus.Broadcast.send_from(host_info(), message)
      error -> error
    end
  end

  @doc """
  Subscribes the calling agent to the broadcasts that reach its host: they arrive in
  `c:handle_info/2` as `{:tartarus_broadcast, from_host, message}`. The subscription ends
  when the agent leaves the host.
  """
  @spec subscribe_broadcasts() :: :ok | {:error, term()}
  def subscribe_broadcasts, do: Tartarus.Broadcast.subscribe(host(), self())

  defp update_payload(fun) do
    env = envelope()
    put_envelope(%{env | payload: %{env.payload | data: fun.(env.payload.data)}})
  end

  @doc false
  # Runs `fun` as agent code of the calling agent process (Tartarus.Agent.Callbacks): with
  # its context (see @ctx above) from `host`, `env` and `children?` (true once it started a
  # process with spawn_link/1) for the functions above. Returns
  # {fun's result, the envelope as fun left it, checkpoint?, children?}. If fun raises,
  # exits or throws, the context stays: call abandon_callback/0.
  @spec run_callback(map(), Envelope.t(), boolean(), (() -> result)) ::
          {result, Envelope.t(), boolean(), boolean()}
        when result: term()
  def run_callback(host, env, children?, fun) do
    Process.put(@ctx, {host, env, false, children?})
    result = fun.()
    {_host, env, checkpoint?, children?} = Process.delete(@ctx)
    {result, env, checkpoint?, children?}
  end

  @doc false
  # After a callback that crashed (run_callback/4): removes its context. True if it had
  # started a process with spawn_link/1 (its process must still end them).
  @spec abandon_callback() :: boolean()
  def abandon_callback do
    case Process.delete(@ctx) do
      {_host, _env, _checkpoint?, children?} -> children?
      _ -> false
    end
  end

  @doc false
  # The calling agent's host map while one of its callbacks runs, else nil (a process that
  # is no agent's, or an agent's between callbacks): Tartarus.Locator's sender.
  @spec calling_host() :: map() | nil
  def calling_host do
    case Process.get(@ctx) do
      {host, _env, _checkpoint?, _children?} -> host
      _ -> nil
    end
  end

  defp context do
    Process.get(@ctx) ||
      raise ArgumentError, "Tartarus.Agent functions must be called from an agent's callbacks"
  end

  defp envelope, do: elem(context(), 1)

  defp host_info, do: elem(context(), 0)

  defp put_envelope(%Envelope{} = env) do
    Process.put(@ctx, put_elem(context(), 1, env))
    :ok
  end
end
