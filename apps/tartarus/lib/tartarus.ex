defmodule Tartarus do
  @moduledoc """
  Tartarus on the BEAM: hosts and mobile agents for decentralized cyber-physical systems.

  This module is the door to the platform; its functions mirror the predicates of the
  Prolog Tartarus (create a static or mobile agent, move, clone, kill, post, add, remove
  and shed payload, list agents, platform status, hop statistics).

  ## Glossary

    * **node** - a BEAM node; in deployment one device (a Raspberry Pi).
    * **host** - a Tartarus Agent Host: where agents live. Addressed as `{name, node}`
      (a bare `name` means a host on this node). A node runs one host in deployment, or
      many in emulation.
    * **neighbours** - a host's overlay links. Agents usually move along them. BEAM nodes
      connect only when their hosts talk, so no full mesh forms.
    * **agent** - a process running a module that `use`s `Tartarus.Agent`. Static agents
      stay on their host and offer services; mobile agents migrate with their state and code.
    * **agent reference** - `{agent, host}` where `agent` is an id or a name and `host` is
      where to start looking; or an id alone for an agent on this node. A reference stays
      valid after the agent moves: hosts leave forwarding pointers that requests follow.

  ## A session

      iex> {:ok, _} = Tartarus.start_host(:doc_a)
      iex> {:ok, _} = Tartarus.start_host(:doc_b, neighbours: [:doc_a])
      iex> Tartarus.neighbours(:doc_a)
      [{:doc_b, node()}]
      iex> {:ok, id} = Tartarus.create_mobile_agent(:doc_a, Tartarus.Examples.Echo, nil)
      iex> Tartarus.move({id, :doc_a}, :doc_b)
      :ok
      iex> Tartarus.request({id, :doc_a}, :where)
      {:ok, {:doc_b, node()}}
      iex> Tartarus.stop_host(:doc_a)
      :ok
      iex> Tartarus.stop_host(:doc_b)
      :ok

  ## Migration semantics

  See `Tartarus.Agent` ("What a move guarantees"): a failed move leaves the agent running
  where it was and calls its `handle_move_failed/4`; a committed move leaves exactly one
  copy, at the destination. Code travels as BEAM binaries checked by md5 and cached per
  node (`Tartarus.CodeCache`).

  ## Events

  Every arrival, departure, failed move, clone, kill, message and shipped byte is counted;
  see `Tartarus.Events`.
  """

  import Bitwise, only: [<<<: 2]
  alias Tartarus.{CodeCache, Envelope, Host, Ledger}

  @typedoc "A host's name: an atom or a string."
  @type host_name :: Host.name()

  @typedoc "A host's address."
  @type host :: Host.t()

  @typedoc "A host: a bare name (on this node) or an address."
  @type host_ref :: host_name() | host()

  @typedoc "An agent's id (16 hex characters)."
  @type agent_id :: String.t()

  @typedoc "Where to find an agent: `{id_or_name, host_to_start_from}`, or an id on this node."
  @type agent_ref :: {agent_id() | String.t(), host_ref()} | agent_id()

  @max_chase 64

  # -- hosts -------------------------------------------------------------------------

  @doc """
  Starts a host named `name` on this node.

  Options:

  #{Tartarus.Options.docs(Host.schema())}

  Returns `{:ok, {name, node()}}`, or `{:error, {:already_started, host}}`, or
  `{:error, message}` for bad options.

  A host whose process tree crashes is not restarted by itself (its agents died with it):
  start it again — on the same `:data_dir` to get its agents back.
  """
  @spec start_host(host_name(), keyword()) :: {:ok, host()} | {:error, term()}
  def start_host(name, opts \\ []) do
    with :ok <- check_name(name),
         {:ok, opts} <- Host.validate_opts(opts) do
      case DynamicSupervisor.start_child(Tartarus.Hosts, %{
             id: name,
             start: {Tartarus.Host.Supervisor, :start_link, [{name, opts}]},
             type: :supervisor,
             restart: :temporary
           }) do
        {:ok, _} ->
          host = Host.address(name)

          with :ok <- attach_all(host, opts[:plugins]),
               :ok <- connect_all(host, opts[:neighbours]),
               {:ok, _agents, _in_doubt} <- Host.call(host, :restore, 60_000) do
            {:ok, host}
          else
            error ->
              stop_host(name)
              error
          end

        {:error, {:already_started, _}} ->
          {:error, {:already_started, Host.address(name)}}

        {:error, {:shutdown, {:failed_to_start_child, _, {:already_started, _}}}} ->
          {:error, {:already_started, Host.address(name)}}

        {:error, reason} ->
          {:error, reason}
      end
    end
  end

  defp check_name(name) do
    if Host.address?(name) and not is_tuple(name),
      do: :ok,
      else:
        {:error,
         "invalid host name given to Tartarus.start_host/2: expected an atom or a string, got: #{inspect(name)}"}
  end

  defp attach_all(host, plugins) do
    Enum.reduce_while(plugins, :ok, fn {name, spec}, :ok ->
      case attach_plugin(host, name, spec) do
        :ok -> {:cont, :ok}
        error -> {:halt, error}
      end
    end)
  end

  defp connect_all(host, neighbours) do
    Enum.reduce_while(neighbours, :ok, fn n, :ok ->
      case connect(host, n) do
        :ok -> {:cont, :ok}
        error -> {:halt, error}
      end
    end)
  end

  @doc """
  Stops a host (on this node or another). Its resident agents stop with it.
  """
  @spec stop_host(host_ref()) :: :ok | {:error, {:unknown_host, term()}}
  def stop_host(host) do
    on_node(host, :stop_local_host, [])
  end

  @doc false
  def stop_local_host({name, _}) do
    case Registry.lookup(Tartarus.HostRegistry, {:host_sup, name}) do
      [{pid, _}] ->
        _ = DynamicSupervisor.terminate_child(Tartarus.Hosts, pid)
        :ok

      [] ->
        {:error, {:unknown_host, Host.address(name)}}
    end
  end

  @doc "The hosts running on this node."
  @spec hosts() :: [host()]
  def hosts do
    Registry.select(Tartarus.HostRegistry, [{{{:host, :"$1"}, :_, :_}, [], [:"$1"]}])
    |> Enum.map(&Host.address/1)
    |> Enum.sort()
  end

  @doc """
  Links hosts `a` and `b` (symmetric). `props` may set `:latency_ms` (each hand-off over the
  link is delayed that long) and `:loss` (probability that a hand-off over the link fails),
  used by emulations.
  """
  @spec connect(host_ref(), host_ref(), keyword()) :: :ok | {:error, term()}
  def connect(a, b, props \\ []) do
    with {:ok, props} <- Tartarus.Options.validate(props, link_schema(), "Tartarus.connect/3") do
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

  defp link_schema do
    [
      latency_ms: [type: :non_neg_integer, default: 0, doc: "delay of each hand-off"],
      loss: [type: :probability, default: 0, doc: "probability a hand-off fails"]
    ]
  end

  @doc "Removes the link between hosts `a` and `b`."
  @spec disconnect(host_ref(), host_ref()) :: :ok | {:error, term()}
  def disconnect(a, b) do
    a = Host.address(a)
    b = Host.address(b)
    r1 = Host.call(a, {:disconnect, b})
    r2 = Host.call(b, {:disconnect, a})
    if r1 == :ok or r2 == :ok, do: :ok, else: r1
  end

  @doc "The neighbours of a host."
  @spec neighbours(host_ref()) :: [host()] | {:error, term()}
  def neighbours(host), do: on_node(host, :local_neighbours, [])

  @doc false
  def local_neighbours(host), do: with({:ok, h} <- Host.local(host), do: Ledger.neighbours(h))

  # -- agents ----------------------------------------------------------------------

  @create_schema [
    name: [type: :any, doc: "a name for the agent (defaults to module and id)"],
    static: [type: :boolean, default: false, doc: "a static agent never leaves its host"],
    owner: [type: :any, doc: "a pid that receives `{:tartarus_result, id, result}`"],
    ttl: [type: :pos_integer_or_infinity, default: :infinity, doc: "maximum number of hops"],
    seed: [type: :any, doc: "seed of the agent's random choices (defaults to its id)"],
    payload: [type: :any, default: %{}, doc: "initial data payload (a map)"],
    modules: [type: {:list, :atom}, default: [], doc: "extra modules to carry in the payload"],
    issuer: [
      type: :any,
      doc: "a key pair (`Tartarus.Security.Keys.generate/0`) to sign the agent with"
    ]
  ]

  @doc """
  Creates an agent of `module` on `host`, calling `module.init(args)` there.

  Options:

  #{Tartarus.Options.docs(@create_schema)}

  Returns `{:ok, id}`, or `{:error, reason}`: `{:not_an_agent, module}`,
  `{:unknown_host, host}`, `{:init_failed, reason}`, or a message for bad options.
  """
  @spec create_agent(host_ref(), module(), term(), keyword()) ::
          {:ok, agent_id()} | {:error, term()}
  def create_agent(host, module, args, opts \\ []) do
    with {:ok, opts} <-
           Tartarus.Options.validate(opts, @create_schema, "Tartarus.create_agent/4"),
         :ok <- check_agent_module(module),
         :ok <- check_payload(opts[:payload]),
         host = Host.address(host),
         {:ok, env} <- sign(new_envelope(host, module, opts), opts[:issuer]),
         :ok <- ensure_code(host, env) do
      Host.call(host, {:create, env, args}, 30_000)
    end
  end

  @doc "Creates a static agent (one that never moves). See `create_agent/4`."
  @spec create_static_agent(host_ref(), module(), term(), keyword()) ::
          {:ok, agent_id()} | {:error, term()}
  def create_static_agent(host, module, args, opts \\ []),
    do: create_agent(host, module, args, Keyword.put(opts, :static, true))

  @doc "Creates a mobile agent. See `create_agent/4`."
  @spec create_mobile_agent(host_ref(), module(), term(), keyword()) ::
          {:ok, agent_id()} | {:error, term()}
  def create_mobile_agent(host, module, args, opts \\ []),
    do: create_agent(host, module, args, Keyword.put(opts, :static, false))

  defp check_agent_module(module) do
    if Tartarus.Agent.agent_module?(module), do: :ok, else: {:error, {:not_an_agent, module}}
  end

  defp sign(env, nil), do: {:ok, env}

  defp sign(env, keys) do
    if Tartarus.Security.keys?(keys) do
      with {:ok, manifest} <- CodeCache.manifest(Envelope.modules(env)),
           do: {:ok, Tartarus.Security.issue(env, manifest, keys)}
    else
      {:error,
       "invalid options given to Tartarus.create_agent/4 for key :issuer: expected a key pair, got: #{inspect(keys)}"}
    end
  end

  defp check_payload(p) when is_map(p), do: Envelope.portable?(p)
  defp check_payload(p), do: {:error, "invalid payload: expected a map, got: #{inspect(p)}"}

  defp new_envelope(host, module, opts) do
    id = Envelope.new_id()

    %Envelope{
      id: id,
      name: opts[:name] || "#{inspect(module)}-#{binary_part(id, 0, 6)}",
      module: module,
      ships: module.__tartarus_agent__(:ships),
      payload: %{data: opts[:payload], modules: opts[:modules]},
      owner: opts[:owner],
      home: host,
      ttl: opts[:ttl],
      static: opts[:static],
      rng: Envelope.seed_rng(Keyword.get(opts, :seed, id))
    }
  end

  # Creating an agent on another node ships its code there first, like a migration would.
  defp ensure_code({_, node}, _env) when node == node(), do: :ok

  defp ensure_code({_, node}, env) do
    with {:ok, manifest} <- CodeCache.manifest(Envelope.modules(env)) do
      case :erpc.call(node, CodeCache, :check, [manifest], 10_000) do
        :ok ->
          :ok

        {:need, mods} ->
          code =
            for m <- mods,
                {_, md5} = List.keyfind(manifest, m, 0),
                {:ok, bin} = CodeCache.fetch_binary(m, md5),
                do: {m, md5, bin}

          :erpc.call(node, CodeCache, :load, [code], 30_000)

        error ->
          error
      end
    end
  catch
    _, _ -> {:error, {:unknown_host, {:node, node}}}
  end

  @doc """
  Orders an agent to move to `dest` (a host or a strategy, see `Tartarus.Strategy`).
  Returns `:ok` once the agent runs at the destination, or `{:error, reason}` when the
  move failed (the agent then keeps running where it was, and its `handle_move_failed/4`
  was called).
  """
  @spec move(agent_ref(), Tartarus.Agent.dest()) :: :ok | {:error, term()}
  def move(agent, dest), do: handoff_call(agent, {:move, dest}, @max_chase)

  @doc """
  Clones an agent to `dest` (a host, a strategy, or `:here`). The clone gets a new id and
  name and starts in `handle_arrival/2` with `ctx.clone_of` set. Returns `{:ok, clone_id}`
  once the clone runs. If the agent's process ends (it moved on) before an answer comes,
  the request is not repeated — that could make two clones — and the result is
  `{:error, {:outcome_unknown, reason}}` when no clone answered within 10 s.
  """
  @spec clone(agent_ref(), Tartarus.Agent.dest() | :here) :: {:ok, agent_id()} | {:error, term()}
  def clone(agent, dest), do: handoff_call(agent, {:clone, dest}, @max_chase)

  # A move or clone ordered from outside. Not a GenServer.call: the agent's process may end
  # before it answers (its move commits, or it moves on after starting a clone), and the
  # answer then comes from the agent's, or the clone's, new process.
  defp handoff_call(_agent, _op, 0), do: {:error, :too_many_hops}

  defp handoff_call(agent, op, n) do
    with {:ok, pid, ref} <- locate(agent) do
      mref = Process.monitor(pid)
      send(pid, {:"$gen_call", {self(), mref}, op})

      receive do
        {^mref, {:error, :in_transit}} ->
          Process.demonitor(mref, [:flush])
          backoff(n)
          handoff_call(ref, op, n - 1)

        {^mref, reply} ->
          Process.demonitor(mref, [:flush])
          reply

        {:DOWN, ^mref, :process, _, reason} ->
          after_down(op, mref, reason, ref, n)
      after
        60_000 ->
          Process.demonitor(mref, [:flush])
          {:error, :timeout}
      end
    end
  end

  # This move committed (the exit names our request): the answer comes from the new process
  # once it runs; if its node dies first, the agent went down with it.
  defp after_down({:move, _}, mref, {:shutdown, {:migrated, new_pid, {_, tag}}}, _ref, _n)
       when tag == mref do
    new_ref = Process.monitor(new_pid)

    receive do
      {^mref, reply} ->
        Process.demonitor(new_ref, [:flush])
        reply

      {:DOWN, ^new_ref, :process, _, reason} ->
        receive do
          {^mref, reply} -> reply
        after
          0 -> {:error, {:destination_down, reason}}
        end
    after
      60_000 ->
        Process.demonitor(new_ref, [:flush])
        {:error, :timeout}
    end
  end

  # The agent's process ended before it took our move: look for the agent again.
  defp after_down({:move, _} = op, _mref, _reason, ref, n), do: handoff_call(ref, op, n - 1)

  # A clone is never retried (that could make a second clone): if the agent took the
  # request, the answer still comes from the clone.
  defp after_down({:clone, _}, mref, reason, _ref, _n) do
    receive do
      {^mref, reply} -> reply
    after
      10_000 -> {:error, {:outcome_unknown, reason}}
    end
  end

  @doc """
  Kills an agent wherever it is now. It is not restarted. Returns once the agent is down:
  at once, unless it traps exits and is inside a callback; then when the callback returns or
  its budget runs out (the host option `:callback_timeout`; see `Tartarus.Agent`).
  """
  @spec kill(agent_ref()) :: :ok | {:error, term()}
  def kill(agent), do: kill(agent, @max_chase)

  defp kill(_agent, 0), do: {:error, :too_many_hops}

  defp kill(agent, n) do
    with {:ok, {a, host}} <- normalize(agent) do
      # The host answers once the agent is down, within its callback budget.
      case Host.call(host, {:kill, a}, :infinity) do
        {:killed, _id} -> :ok
        {:moved, next} -> kill({a, next}, n - 1)
        {:arriving, _pid} -> backoff(n) && kill({a, host}, n - 1)
        :not_found -> {:error, :not_found}
        error -> error
      end
    end
  end

  @doc """
  Posts `message` to an agent. Returns `:ok` once the agent has taken the message (its
  `handle_message/3` is called with `from = nil`), following the agent if it moved;
  `{:error, :not_found}` if no such agent exists where the search leads.
  """
  @spec post(agent_ref(), term(), timeout()) :: :ok | {:error, term()}
  def post(agent, message, timeout \\ 5_000),
    do: deliver(agent, :post, message, timeout, @max_chase)

  @doc """
  Posts `message` to an agent without waiting: a short-lived process delivers it with the
  same guarantees as `post/3` (it follows the agent if it moves). Use it from an agent's
  callbacks to message other agents: two agents that `post/3` to each other from their
  callbacks would wait for each other. The outcome, if not `:ok`, is sent to `reply_to`
  (when given) as `{:tartarus_cast_failed, agent, reason}`.
  """
  @spec cast(agent_ref(), term(), pid() | nil) :: :ok
  def cast(agent, message, reply_to \\ nil) do
    spawn(fn ->
      case post(agent, message) do
        :ok ->
          :ok

        {:error, reason} ->
          if reply_to, do: send(reply_to, {:tartarus_cast_failed, agent, reason})
      end
    end)

    :ok
  end

  @doc """
  Sends `message` to an agent and waits for its reply (the agent answers with
  `Tartarus.Agent.reply/2`). Returns `{:ok, reply}` or `{:error, :timeout | :not_found}`, or
  `{:error, {:callback_timeout, :handle_message, ms}}` if the agent's `handle_message/3`
  overran its host's callback budget (the agent is then removed, see `Tartarus.Agent`).
  """
  @spec request(agent_ref(), term(), timeout()) :: {:ok, term()} | {:error, term()}
  def request(agent, message, timeout \\ 5_000),
    do: deliver(agent, :request, message, timeout, @max_chase)

  defp deliver(_agent, _kind, _msg, _timeout, 0), do: {:error, :too_many_hops}

  defp deliver(agent, kind, msg, timeout, n) do
    with {:ok, pid, ref} <- locate(agent) do
      tag = Process.monitor(pid)
      send(pid, {:"$tartarus_msg", {self(), tag}, kind, msg})

      receive do
        {^tag, :delivered} ->
          Process.demonitor(tag, [:flush])

          if kind == :post do
            :ok
          else
            receive do
              {^tag, {:reply, value}} -> {:ok, value}
              {^tag, {:error, {:callback_timeout, _, _}} = error} -> error
            after
              timeout -> {:error, :timeout}
            end
          end

        {:DOWN, ^tag, :process, _, _} ->
          # The agent left (or died) before taking the message: look again.
          backoff(n)
          deliver(ref, kind, msg, timeout, n - 1)
      after
        timeout ->
          Process.demonitor(tag, [:flush])
          {:error, :timeout}
      end
    end
  end

  @doc """
  Finds the host an agent is on now, following forwarding pointers.
  """
  @spec whereis(agent_ref()) :: {:ok, host()} | {:error, term()}
  def whereis(agent) do
    with {:ok, _pid, {_, host}} <- locate(agent), do: {:ok, host}
  end

  @doc """
  Information about an agent: id, name, module, host, home, hops, state, payload.
  """
  @spec agent_info(agent_ref()) :: {:ok, map()} | {:error, term()}
  def agent_info(agent) do
    case control(agent, :info) do
      %{} = info -> {:ok, info}
      error -> error
    end
  end

  @doc "Adds (or replaces) `key` in an agent's data payload."
  @spec add_payload(agent_ref(), term(), term()) :: :ok | {:error, term()}
  def add_payload(agent, key, value), do: control(agent, {:payload, {:add, key, value}})

  @doc "Removes `key` from an agent's data payload."
  @spec remove_payload(agent_ref(), term()) :: :ok | {:error, term()}
  def remove_payload(agent, key), do: control(agent, {:payload, {:remove, key}})

  @doc "Sheds `key` of an agent's payload to the store of the host it is on."
  @spec shed_payload(agent_ref(), term()) :: :ok | {:error, term()}
  def shed_payload(agent, key), do: control(agent, {:payload, {:shed, key}})

  @doc "Copies `key` of an agent's payload to the store of the host it is on."
  @spec copy_payload(agent_ref(), term()) :: :ok | {:error, term()}
  def copy_payload(agent, key), do: control(agent, {:payload, {:copy, key}})

  @doc "Adds a module to the modules an agent carries (it ships wherever the agent goes)."
  @spec add_module(agent_ref(), module()) :: :ok | {:error, term()}
  def add_module(agent, module), do: control(agent, {:payload, {:add_module, module}})

  @doc "An agent's data payload."
  @spec payload(agent_ref()) :: {:ok, map()} | {:error, term()}
  def payload(agent), do: control(agent, {:payload, :get})

  defp control(agent, op, n \\ @max_chase)
  defp control(_agent, _op, 0), do: {:error, :too_many_hops}

  defp control(agent, op, n) do
    with {:ok, pid, ref} <- locate(agent) do
      try do
        GenServer.call(pid, op, 60_000)
      catch
        :exit, {:timeout, _} -> {:error, :timeout}
        :exit, _ -> control(ref, op, n - 1)
      else
        {:error, :in_transit} ->
          Process.sleep(5)
          control(ref, op, n - 1)

        result ->
          result
      end
    end
  end

  # Finds an agent's pid. Returns the reference normalized to `{id, host}`.
  defp locate(agent, n \\ @max_chase)
  defp locate(_agent, 0), do: {:error, :too_many_hops}

  defp locate(agent, n) do
    with {:ok, {a, host}} <- normalize(agent) do
      result =
        case Host.local(host) do
          {:ok, info} -> Ledger.locate(info, a)
          _ -> Host.call(host, {:locate, a})
        end

      case result do
        {:here, pid, id} -> {:ok, pid, {id, host}}
        {:moved, next} -> locate({a, next}, n - 1)
        {:arriving, _pid} -> backoff(n) && locate({a, host}, n - 1)
        :not_found -> {:error, :not_found}
        error -> error
      end
    end
  end

  # Between retries of an agent caught in a hand-off: 1, 2, 4 ... 200 ms, about 12 s in all
  # (a paused copy in doubt waits for the migration timeout, 5 s by default, then asks).
  defp backoff(n) do
    Process.sleep(min(1 <<< min(max(@max_chase - n, 0), 8), 200))
    true
  end

  defp normalize({agent, host}) do
    if Host.address?(host),
      do: {:ok, {agent, Host.address(host)}},
      else: {:error, {:unknown_host, host}}
  end

  defp normalize(id) when is_binary(id) do
    case Tartarus.AgentTable.lookup(id) do
      {:ok, _pid, host_name} ->
        {:ok, {id, Host.address(host_name)}}

      :error ->
        # Perhaps in a hand-off between two hosts of this node: the destination knows.
        case Enum.find(hosts(), &local_arriving?(&1, id)) do
          nil -> {:error, :not_found}
          host -> {:ok, {id, host}}
        end
    end
  end

  defp normalize(other), do: {:error, {:bad_agent_ref, other}}

  defp local_arriving?(host, id) do
    case Host.local(host) do
      {:ok, h} -> :ets.member(h.ledger, {:arriving, id})
      _ -> false
    end
  end

  @doc """
  The agents resident on a host, as maps with `:id`, `:name`, `:module`, `:pid`.
  """
  @spec agents(host_ref()) :: [map()] | {:error, term()}
  def agents(host), do: on_node(host, :local_agents, [])

  @doc false
  def local_agents(host) do
    with {:ok, h} <- Host.local(host) do
      h
      |> Ledger.residents()
      |> Enum.map(fn {id, name, module, pid} ->
        %{id: id, name: name, module: module, pid: pid}
      end)
      |> Enum.sort_by(& &1.name)
    end
  end

  @doc """
  A host's status: resident agents, neighbours, visits, event counts, hop statistics,
  forwarding pointers and plugins.
  """
  @spec status(host_ref()) :: map() | {:error, term()}
  def status(host), do: on_node(host, :local_status, [])

  @doc false
  def local_status(host) do
    with {:ok, h} <- Host.local(host) do
      %{
        host: h.ref,
        resident: Ledger.counter(h, :resident),
        visits: Ledger.counter(h, :visits),
        neighbours: Ledger.neighbours(h),
        counts: Tartarus.Events.host_counts(h),
        hops: hop_summary(Ledger.hop_times(h)),
        forwarding_pointers: length(Ledger.forwarding_pointers(h)),
        plugins: Tartarus.Plugin.list(elem(h.ref, 0))
      }
    end
  end

  @doc """
  Statistics of the most recent (up to 1024) hop times of arrivals at a host, in µs:
  `%{count, median_us, p99_us, mean_us, max_us}`. A hop time runs from the moment the
  source froze the agent to its start at the destination (both clocks must agree: on one
  machine they do).
  """
  @spec hop_stats(host_ref()) :: map() | {:error, term()}
  def hop_stats(host), do: on_node(host, :local_hop_stats, [])

  @doc false
  def local_hop_times(host), do: with({:ok, h} <- Host.local(host), do: Ledger.hop_times(h))

  @doc false
  def local_hop_stats(host),
    do: with({:ok, h} <- Host.local(host), do: hop_summary(Ledger.hop_times(h)))

  @doc false
  def hop_summary([]), do: %{count: 0, median_us: nil, p99_us: nil, mean_us: nil, max_us: nil}

  def hop_summary(times) do
    sorted = Enum.sort(times)
    n = length(sorted)

    %{
      count: n,
      median_us: percentile(sorted, 0.5),
      p99_us: percentile(sorted, 0.99),
      mean_us: Enum.sum(sorted) / n,
      max_us: List.last(sorted)
    }
  end

  @doc """
  The value at quantile `q` (0..1) of a sorted non-empty list (nearest rank).

      iex> Tartarus.percentile([1, 2, 3, 4, 5], 0.5)
      3
  """
  @spec percentile([number()], float()) :: number()
  def percentile(sorted, q),
    do: Enum.at(sorted, min(length(sorted) - 1, max(0, ceil(q * length(sorted)) - 1)))

  @doc "Reads `key` from a host's store."
  @spec store_get(host_ref(), term(), term()) :: term()
  def store_get(host, key, default \\ nil), do: on_node(host, :local_store_get, [key, default])

  @doc false
  def local_store_get(host, key, default) do
    with {:ok, h} <- Host.local(host) do
      case :ets.lookup(h.store, key) do
        [{_, v}] -> v
        [] -> default
      end
    end
  end

  @doc "Writes `key` in a host's store."
  @spec store_put(host_ref(), term(), term()) :: :ok | {:error, term()}
  def store_put(host, key, value), do: on_node(host, :local_store_put, [key, value])

  @doc false
  def local_store_put(host, key, value) do
    with {:ok, h} <- Host.local(host) do
      :ets.insert(h.store, {key, value})
      :ok
    end
  end

  # -- plugins ---------------------------------------------------------------------

  @doc """
  Attaches a plugin (a device) to a host under `name`: `spec` is `{module, opts}` with
  `module` implementing `Tartarus.Plugin`. Agents on the host reach it with
  `Tartarus.Agent.read/2` and friends.
  """
  @spec attach_plugin(host_ref(), atom(), {module(), keyword()}) :: :ok | {:error, term()}
  def attach_plugin(host, name, spec), do: on_node(host, :local_attach_plugin, [name, spec])

  @doc false
  def local_attach_plugin({host_name, _} = host, name, {module, opts})
      when is_atom(name) and is_atom(module) do
    with {:ok, _} <- Host.local(host),
         true <-
           (Code.ensure_loaded?(module) and function_exported?(module, :read, 2)) ||
             {:error, {:not_a_plugin, module}} do
      sup = Tartarus.Host.Supervisor.via(:plugins, host_name)

      case DynamicSupervisor.start_child(sup, {Tartarus.Plugin, {host_name, name, module, opts}}) do
        {:ok, _} -> :ok
        {:error, {:already_started, _}} -> {:error, {:already_attached, name}}
        {:error, reason} -> {:error, reason}
      end
    end
  end

  def local_attach_plugin(_host, name, spec), do: {:error, {:bad_plugin, name, spec}}

  @doc """
  Reads from plugin `name` of a host, from outside any agent (an operator in iex, a test,
  an emulation driver feeding simulated devices). Agents use `Tartarus.Agent.read/2`.
  """
  @spec read_plugin(host_ref(), atom(), term()) :: {:ok, term()} | {:error, term()}
  def read_plugin(host, name, args \\ nil),
    do: on_node(host, :local_plugin_call, [name, {:read, args}])

  @doc "Writes to plugin `name` of a host, from outside any agent. See `read_plugin/3`."
  @spec write_plugin(host_ref(), atom(), term()) :: :ok | {:error, term()}
  def write_plugin(host, name, args),
    do: on_node(host, :local_plugin_call, [name, {:write, args}])

  @doc false
  def local_plugin_call(host, name, request), do: Tartarus.Plugin.call(host, name, request)

  @doc "The plugins attached to a host, with their descriptions."
  @spec plugins(host_ref()) :: [{atom(), map()}] | {:error, term()}
  def plugins(host), do: on_node(host, :local_plugins, [])

  @doc false
  def local_plugins(host),
    do: with({:ok, h} <- Host.local(host), do: Tartarus.Plugin.list(elem(h.ref, 0)))

  # -- code --------------------------------------------------------------------------

  @doc """
  Compiles Elixir source at run time and registers the resulting modules so they can ship
  to other nodes (on-the-fly programming). Returns the compiled modules.
  Agent modules typed in iex are registered automatically; this is for helper modules and
  scripts.
  """
  @spec compile_string(String.t()) :: {:ok, [module()]} | {:error, term()}
  def compile_string(source) when is_binary(source) do
    modules = Code.compile_string(source)
    Enum.each(modules, fn {mod, bin} -> CodeCache.remember(mod, bin) end)
    {:ok, Enum.map(modules, &elem(&1, 0))}
  rescue
    e -> {:error, {:compile_error, Exception.message(e)}}
  end

  # -- helpers -----------------------------------------------------------------------

  # Runs `local_<fun>` for a host on this node, or remotely on the host's node.
  defp on_node(host, fun, args) do
    if Host.address?(host) do
      {_, node} = host = Host.address(host)

      if node == node() do
        try do
          apply(__MODULE__, fun, [host | args])
        rescue
          # The host stopped while we read its tables.
          ArgumentError -> {:error, {:unknown_host, host}}
        end
      else
        try do
          :erpc.call(node, __MODULE__, fun, [host | args], 10_000)
        catch
          _, _ -> {:error, {:unknown_host, host}}
        end
      end
    else
      {:error, {:unknown_host, host}}
    end
  end
end
