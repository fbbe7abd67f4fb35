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

  ## Where the work is done

  This module checks nothing itself and only delegates, so it reads as the list of what the
  platform offers. `Tartarus.Options.Platform` validates every option list (the admission
  policy's limits are `Tartarus.Security.Admission`'s). Internal modules do the rest:
  Tartarus.Host.Starter builds a host's process tree, Tartarus.Host.Links keeps the overlay,
  Tartarus.Agent.Creator builds (and signs) new agents, Tartarus.CodeShipping ships code to
  other nodes (for creations here and, in the agent server, for migrations),
  Tartarus.Locator finds and chases agents, and Tartarus.Host.OnNode runs reads and writes
  of a host on the host's node.

  ## Events

  Every arrival, departure, failed move, clone, kill, message and shipped byte is counted;
  see `Tartarus.Events`.
  """

  alias Tartarus.{CodeCache, Host, Locator}
  alias Tartarus.Host.OnNode
  alias Tartarus.Options.Platform

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

  # -- hosts -------------------------------------------------------------------------

  @doc """
  Starts a host named `name` on this node.

  Options:

  #{Tartarus.Options.docs(Platform.host_schema())}

  Returns `{:ok, {name, node()}}`, or `{:error, {:already_started, host}}`, or
  `{:error, message}` for bad options.

  A host whose process tree crashes is restarted (up to 3 times in 5 seconds, then it stops
  for good): its plugins are attached again, the neighbours of its start options linked
  again, and, with `:data_dir`, its agents restored from the journal (without persistence
  its agents died with it). Links added later by `connect/3` are not remembered.
  """
  @spec start_host(host_name(), keyword()) :: {:ok, host()} | {:error, term()}
  def start_host(name, opts \\ []), do: Host.Starter.start(name, opts)

  @doc """
  Stops a host (on this node or another). Its resident agents stop with it.
  """
  @spec stop_host(host_ref()) :: :ok | {:error, {:unknown_host, term()}}
  def stop_host(host), do: OnNode.run(host, :stop_host, [])

  @doc "The hosts running on this node. For the hosts of every node, see `fleet/1`."
  @spec hosts() :: [host()]
  def hosts, do: Host.Starter.hosts()

  @doc """
  The fleet as this node sees it: every node reachable through the overlay, with its hosts
  and their agents, sorted by node. Each node is
  `%{node: node, agents: count, hosts: [%{host: address, agents: count, neighbours: [address]}]}`
  (`agents`: resident agents). A node named as a neighbour that did not answer within
  `timeout` ms (down, cut off, too slow) is listed as
  `%{node: node, agents: 0, hosts: [], error: :not_reached}`.

  It is read as an agent known by its id alone is searched for: this node's hosts'
  neighbours' nodes are asked, and they ask theirs, each node once, at most 32 overlay hops
  away, in one time budget; no node connects to a node it has no link with. A node without
  hosts (a shell attached to the fleet) asks the nodes it is connected to, and is listed
  with no hosts.

      iex> {:ok, a} = Tartarus.start_host(:doc_fleet_a)
      iex> {:ok, _} = Tartarus.create_mobile_agent(a, Tartarus.Examples.Echo, nil)
      iex> [me] = Enum.filter(Tartarus.fleet(), &(&1.node == node()))
      iex> Enum.find(me.hosts, &(&1.host == a))
      %{host: {:doc_fleet_a, node()}, agents: 1, neighbours: []}
      iex> Tartarus.stop_host(a)
      :ok
  """
  @spec fleet(timeout()) :: [map()]
  def fleet(timeout \\ 5_000), do: Tartarus.Locator.Walk.fleet(timeout)

  @doc """
  Links hosts `a` and `b` (symmetric). Link properties:

  #{Tartarus.Options.docs(Platform.link_schema())}

  The platform keeps them for a transport (`Tartarus.Transport`), which only an emulator
  installs; the emulator's applies them as follows. `:latency_ms` is the one-way delay of
  one message over the link:
  a hand-off over it pays three (prepare, prepared, commit: what stands between the
  source's decision to move and the agent running at the destination), and a message an
  agent sends to an agent on the other end (`post/3`, `cast/3`, `request/3` called from
  its callbacks) pays one on the way there and one on the way back (acknowledgement or
  reply). Messages between hosts that are not neighbours, or sent from outside any agent,
  pay nothing. `:loss` makes a hand-off over the link fail with that probability.
  """
  @spec connect(host_ref(), host_ref(), keyword()) :: :ok | {:error, term()}
  def connect(a, b, props \\ []), do: Host.Links.connect(a, b, props)

  @doc "Removes the link between hosts `a` and `b`."
  @spec disconnect(host_ref(), host_ref()) :: :ok | {:error, term()}
  def disconnect(a, b), do: Host.Links.disconnect(a, b)

  @doc "The neighbours of a host."
  @spec neighbours(host_ref()) :: [host()] | {:error, term()}
  def neighbours(host), do: OnNode.run(host, :neighbours, [])

  # -- agents ----------------------------------------------------------------------

  @doc """
  Creates an agent of `module` on `host`, calling `module.init(args)` there.

  Options:

  #{Tartarus.Options.docs(Platform.create_agent_schema())}

  Returns `{:ok, id}`, or `{:error, reason}`: `{:not_an_agent, module}`,
  `{:unknown_host, host}`, `{:init_failed, reason}`, or a message for bad options.
  """
  @spec create_agent(host_ref(), module(), term(), keyword()) ::
          {:ok, agent_id()} | {:error, term()}
  def create_agent(host, module, args, opts \\ []),
    do: Tartarus.Agent.Creator.create(host, module, args, opts)

  @doc "Creates a static agent (one that never moves). See `create_agent/4`."
  @spec create_static_agent(host_ref(), module(), term(), keyword()) ::
          {:ok, agent_id()} | {:error, term()}
  def create_static_agent(host, module, args, opts \\ []),
    do: create_agent(host, module, args, put_opt(opts, :static, true))

  @doc "Creates a mobile agent. See `create_agent/4`."
  @spec create_mobile_agent(host_ref(), module(), term(), keyword()) ::
          {:ok, agent_id()} | {:error, term()}
  def create_mobile_agent(host, module, args, opts \\ []),
    do: create_agent(host, module, args, put_opt(opts, :static, false))

  # Bad options are left for create_agent/4 to name.
  defp put_opt(opts, key, value) do
    if is_list(opts) and Keyword.keyword?(opts), do: Keyword.put(opts, key, value), else: opts
  end

  @doc """
  Orders an agent to move to `dest` (a host or a strategy, see `Tartarus.Strategy`).
  Returns `:ok` once the agent runs at the destination, or `{:error, reason}` when the
  move failed (the agent then keeps running where it was, and its `handle_move_failed/4`
  was called).
  """
  @spec move(agent_ref(), Tartarus.Agent.dest()) :: :ok | {:error, term()}
  def move(agent, dest), do: Locator.handoff(agent, {:move, dest})

  @doc """
  Clones an agent to `dest` (a host, a strategy, or `:here`). The clone gets a new id and
  name and starts in `handle_arrival/2` with `ctx.clone_of` set. Returns `{:ok, clone_id}`
  once the clone runs. If the agent's process ends (it moved on) before an answer comes,
  the request is not repeated — that could make two clones — and the result is
  `{:error, {:outcome_unknown, reason}}` when no clone answered within 10 s.
  """
  @spec clone(agent_ref(), Tartarus.Agent.dest() | :here) :: {:ok, agent_id()} | {:error, term()}
  def clone(agent, dest), do: Locator.handoff(agent, {:clone, dest})

  @doc """
  Kills an agent wherever it is now. It is not restarted. Returns once the agent is down:
  at once, unless it traps exits and is inside a callback; then when the callback returns or
  its budget runs out (the host option `:callback_timeout`; see `Tartarus.Agent`).
  """
  @spec kill(agent_ref()) :: :ok | {:error, term()}
  def kill(agent), do: Locator.kill(agent)

  @doc """
  Posts `message` to an agent. Returns `:ok` once the agent has taken the message (its
  `handle_message/3` is called with `from = nil`), following the agent if it moved;
  `{:error, :not_found}` if no such agent exists where the search leads.

  The message follows an agent that keeps moving (it is handed on with the agent, and
  taken once), and a sender's posts are handled in the order it made them. A paused copy
  whose stash is full tells the sender to send again (it backs off briefly), so posts to a
  busy moving agent queue at their senders instead of being lost.

  What an error means: every error but `{:error, :timeout}` means the message was not
  taken and will not be. `{:error, :timeout}` means the outcome is unknown: the message
  may still be on its way (in a mailbox or carried by the agent's hand-off) and be handled
  after the caller gave up. On a host
  started with `durable: true`, `:ok` means the agent has handled the message and
  checkpointed the resulting state (journaled with `data_dir:`); a message whose handling
  crashes the agent returns `{:error, :agent_crashed}`.
  """
  @spec post(agent_ref(), term(), timeout()) :: :ok | {:error, term()}
  def post(agent, message, timeout \\ 5_000), do: Locator.deliver(agent, :post, message, timeout)

  @doc """
  Posts `message` to an agent without waiting: a short-lived process delivers it with the
  same guarantees as `post/3` (it follows the agent if it moves). Use it from an agent's
  callbacks to message other agents: two agents that `post/3` to each other from their
  callbacks would wait for each other. The outcome, if not `:ok`, is sent to `reply_to`
  (when given): `{:tartarus_cast_failed, agent, reason}` means the message was not taken
  and will not be; `{:tartarus_cast_unknown, agent, :timeout}` means the platform does not
  know (no delivery was confirmed within 5 s; it may still be handled).
  """
  @spec cast(agent_ref(), term(), pid() | nil) :: :ok
  def cast(agent, message, reply_to \\ nil) do
    from = Locator.sender()

    spawn(fn ->
      case Locator.deliver(agent, :post, message, 5_000, from) do
        :ok ->
          :ok

        {:error, :timeout} ->
          if reply_to, do: send(reply_to, {:tartarus_cast_unknown, agent, :timeout})

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
  overran its host's callback budget (the agent is then removed, see `Tartarus.Agent`), or,
  as soon as it happens, `{:error, {:agent_crashed, reason}}` when the agent's process
  crashed after it took the request without answering (its host restarts it from its
  snapshot; the request is not handled again) and `{:error, {:agent_ended, reason}}` when
  it ended otherwise without answering (it stopped).
  """
  @spec request(agent_ref(), term(), timeout()) :: {:ok, term()} | {:error, term()}
  def request(agent, message, timeout \\ 5_000),
    do: Locator.deliver(agent, :request, message, timeout)

  @doc """
  Finds the host an agent is on now, following forwarding pointers.
  """
  @spec whereis(agent_ref()) :: {:ok, host()} | {:error, term()}
  def whereis(agent) do
    with {:ok, _pid, {_, host}} <- Locator.locate(agent), do: {:ok, host}
  end

  @doc """
  Information about an agent: id, name, module, host, home, hops, state, payload.
  """
  @spec agent_info(agent_ref()) :: {:ok, map()} | {:error, term()}
  def agent_info(agent) do
    case Locator.control(agent, :info) do
      %{} = info -> {:ok, info}
      error -> error
    end
  end

  @doc "Adds (or replaces) `key` in an agent's data payload."
  @spec add_payload(agent_ref(), term(), term()) :: :ok | {:error, term()}
  def add_payload(agent, key, value),
    do: Locator.control(agent, {:payload, {:add, key, value}})

  @doc "Removes `key` from an agent's data payload."
  @spec remove_payload(agent_ref(), term()) :: :ok | {:error, term()}
  def remove_payload(agent, key), do: Locator.control(agent, {:payload, {:remove, key}})

  @doc "Sheds `key` of an agent's payload to the store of the host it is on."
  @spec shed_payload(agent_ref(), term()) :: :ok | {:error, term()}
  def shed_payload(agent, key), do: Locator.control(agent, {:payload, {:shed, key}})

  @doc "Copies `key` of an agent's payload to the store of the host it is on."
  @spec copy_payload(agent_ref(), term()) :: :ok | {:error, term()}
  def copy_payload(agent, key), do: Locator.control(agent, {:payload, {:copy, key}})

  @doc "Adds a module to the modules an agent carries (it ships wherever the agent goes)."
  @spec add_module(agent_ref(), module()) :: :ok | {:error, term()}
  def add_module(agent, module), do: Locator.control(agent, {:payload, {:add_module, module}})

  @doc "An agent's data payload."
  @spec payload(agent_ref()) :: {:ok, map()} | {:error, term()}
  def payload(agent), do: Locator.control(agent, {:payload, :get})

  @doc """
  The agents resident on a host, as maps with `:id`, `:name`, `:module`, `:pid`. A host's
  short name means this node's host of that name, else the neighbour of that name of this
  node's hosts (as a destination does; two such neighbours answer
  `{:error, {:ambiguous_host, name, candidates}}`).
  """
  @spec agents(host_ref()) :: [map()] | {:error, term()}
  def agents(host),
    do: with({:ok, host} <- Locator.resolve_host(host), do: OnNode.run(host, :agents, []))

  @doc """
  Every agent resident on this node's hosts, as `agents/1` gives them plus `:host` (its
  host's address), in no particular order: one read of the node's agent table, however many
  hosts the node has (`agents/1` host by host costs a scan of each host's ledger). Only
  agents that exist: a stopped host's agents leave the table with it, and an entry whose
  process is gone is not listed.
  """
  @spec agents() :: [map()]
  def agents, do: Tartarus.AgentTable.all()

  @doc """
  A host's status: resident agents, neighbours, visits, event counts, hop statistics,
  forwarding pointers, plugins and, under `:journal`, its journal (nil without `data_dir:`):
  `:path`, `:bytes`, `:refused_writes` (writes refused since it started, e.g. on a full
  disk), `:last_error` (nil once a write succeeded again) and `:damaged` (nil, or what the
  host could not read when it started: `:ranges` of `{offset, length}`, `:records` read,
  `:moved_to`, the original file kept aside).
  """
  @spec status(host_ref()) :: map() | {:error, term()}
  def status(host),
    do: with({:ok, host} <- Locator.resolve_host(host), do: OnNode.run(host, :status, []))

  @doc """
  Part of a host's status: only the keys asked for (of `:host`, `:resident`, `:visits`,
  `:neighbours`, `:counts`, `:hops`, `:forwarding_pointers`, `:plugins`, `:journal`), each as in
  `status/1`, and only they are computed: `[:resident, :counts]` reads a counter and the
  host's event counts, where the whole status also lists its plugins and pointers (for
  watchers of thousands of hosts).

      iex> Tartarus.status(:no_such_host, [:resident, :colour])
      {:error, {:unknown_status_keys, [:colour]}}
  """
  @spec status(host_ref(), [atom()]) :: map() | {:error, term()}
  def status(host, keys) when is_list(keys) do
    case keys -- OnNode.status_keys() do
      [] -> with {:ok, host} <- Locator.resolve_host(host), do: OnNode.run(host, :status, [keys])
      unknown -> {:error, {:unknown_status_keys, unknown}}
    end
  end

  @doc """
  Statistics of the most recent (up to 1024) hop times of arrivals at a host, in µs:
  `%{count, median_us, p99_us, mean_us, max_us}`. A hop time runs from the moment the
  source froze the agent to its start at the destination (both clocks must agree: on one
  machine they do).
  """
  @spec hop_stats(host_ref()) :: map() | {:error, term()}
  def hop_stats(host), do: OnNode.run(host, :hop_stats, [])

  @doc """
  The most recent (up to 1024) hop times of arrivals at a host, in µs, unsorted: the
  samples `hop_stats/1` summarizes.
  """
  @spec hop_times(host_ref()) :: [non_neg_integer()] | {:error, term()}
  def hop_times(host), do: OnNode.run(host, :hop_times, [])

  @doc "Reads `key` from a host's store."
  @spec store_get(host_ref(), term(), term()) :: term()
  def store_get(host, key, default \\ nil), do: OnNode.run(host, :store_get, [key, default])

  @doc "Writes `key` in a host's store."
  @spec store_put(host_ref(), term(), term()) :: :ok | {:error, term()}
  def store_put(host, key, value), do: OnNode.run(host, :store_put, [key, value])

  # -- plugins ---------------------------------------------------------------------

  @doc """
  Attaches a plugin (a device) to a host under `name`: `spec` is `{module, opts}` with
  `module` implementing `Tartarus.Plugin`. Agents on the host reach it with
  `Tartarus.Agent.read/2` and friends.
  """
  @spec attach_plugin(host_ref(), atom(), {module(), keyword()}) :: :ok | {:error, term()}
  def attach_plugin(host, name, spec), do: OnNode.run(host, :attach_plugin, [name, spec])

  @doc """
  Reads from plugin `name` of a host, from outside any agent (an operator in iex, a test,
  an emulation driver feeding simulated devices). Agents use `Tartarus.Agent.read/2`.
  """
  @spec read_plugin(host_ref(), atom(), term()) :: {:ok, term()} | {:error, term()}
  def read_plugin(host, name, args \\ nil),
    do: OnNode.run(host, :plugin_call, [name, {:read, args}])

  @doc "Writes to plugin `name` of a host, from outside any agent. See `read_plugin/3`."
  @spec write_plugin(host_ref(), atom(), term()) :: :ok | {:error, term()}
  def write_plugin(host, name, args),
    do: OnNode.run(host, :plugin_call, [name, {:write, args}])

  @doc "The plugins attached to a host, with their descriptions."
  @spec plugins(host_ref()) :: [{atom(), map()}] | {:error, term()}
  def plugins(host), do: OnNode.run(host, :plugins, [])

  @doc """
  What a host can do, as its plugins describe it: `%{capability => [plugin names]}` (see
  `Tartarus.Plugin`, "Capabilities"), so agents and operators choose robots by what they
  can do.
  """
  @spec capabilities(host_ref()) :: %{atom() => [atom()]} | {:error, term()}
  def capabilities(host) do
    case plugins(host) do
      {:error, _} = error -> error
      plugins -> Tartarus.Plugin.capabilities(plugins)
    end
  end

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

  # -- signals and broadcasts (see Tartarus.Signal, Tartarus.Broadcast) ---------------

  @doc """
  Emits signal `name` of strength `strength` at `host`; it spreads to the hosts around it,
  decaying with hops and evaporating with time. See `Tartarus.Signal.emit/4`.
  """
  @spec emit_signal(host_ref(), term(), number(), keyword()) :: :ok | {:error, term()}
  defdelegate emit_signal(host, name, strength, opts \\ []), to: Tartarus.Signal, as: :emit

  @doc "The value of signal `name` at `host` now. See `Tartarus.Signal.value/3`."
  @spec signal(host_ref(), term(), keyword()) :: float() | {:error, term()}
  defdelegate signal(host, name, opts \\ []), to: Tartarus.Signal, as: :value

  @doc """
  Sends `message` to every neighbour of `host`, counted like migrations. See
  `Tartarus.Broadcast`.
  """
  @spec broadcast(host_ref(), term()) :: {:ok, non_neg_integer()} | {:error, term()}
  defdelegate broadcast(host, message), to: Tartarus.Broadcast
end
