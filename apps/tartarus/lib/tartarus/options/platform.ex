defmodule Tartarus.Options.Platform do
  @moduledoc """
  The option schemas of the platform's public constructors, and their validators: every
  one written with `Tartarus.Options`, so each error names the function, the key (or key
  path), what was expected and what arrived.

    * `host/1` - `Tartarus.start_host/2` (with the nested admission policy, see
      `Tartarus.Security.Admission`, and the security options, see `Tartarus.Security`);
    * `create_agent/1` - `Tartarus.create_agent/4` and its static and mobile variants;
    * `link/1` - `Tartarus.connect/3`.

  Example:

      iex> Tartarus.Options.Platform.link(loss: 2)
      {:error, "invalid options given to Tartarus.connect/3 for key :loss: expected a number between 0 and 1, got: 2"}
      iex> {:error, message} = Tartarus.Options.Platform.host(admission: [rate: 5])
      iex> message
      "invalid options given to Tartarus.start_host/2 for key [:admission, :rate]: expected {count, interval_ms} with positive integers, or :infinity, got: 5"
  """

  alias Tartarus.Options
  alias Tartarus.Security.Admission

  @host [
    neighbours: [
      type: {:list, :host},
      default: [],
      doc: "hosts to link to at start (links are symmetric; remote hosts must be running)"
    ],
    max_neighbours: [
      type: :pos_integer,
      default: 256,
      doc:
        "most overlay links the host keeps; more are refused with `{:too_many_neighbours, max}`"
    ],
    migration_timeout: [
      type: :pos_integer,
      default: 5_000,
      doc: "ms to wait for each reply of the hand-off before the source decides to abort"
    ],
    max_restarts: [
      type: :non_neg_integer,
      default: 3,
      doc: "times a crashing agent is restarted from its arrival snapshot before removal"
    ],
    strict_links: [
      type: :boolean,
      default: false,
      doc: "refuse directed moves to hosts that are not neighbours (emulated links)"
    ],
    plugins: [
      type: :keyword,
      default: [],
      doc: "plugins to attach at start, as `name: {module, opts}`"
    ],
    store: [type: :any, default: %{}, doc: "initial contents of the host store (a map)"],
    admission: [
      type: {:keyword, Admission.schema()},
      default: [],
      doc:
        "the admission policy: every limit on one arriving agent (see " <>
          "`Tartarus.Security.Admission`); a host given none gets the finite defaults below"
    ],
    callback_timeout: [
      type: :pos_integer_or_infinity,
      default: 10_000,
      doc:
        "ms each callback of an agent (`init/1`, `handle_arrival/2`, `handle_message/3`, " <>
          "`handle_move_failed/4`, `handle_info/2`) may run; an agent whose callback overruns " <>
          "is stopped and removed (its creator gets `{:error, {:callback_timeout, :init, ms}}`, " <>
          "its owner `{:tartarus_removed, id, {:callback_timeout, callback, ms}}`); the default " <>
          "leaves room for the 5 s calls a callback may make. With `:infinity` nothing bounds them"
    ],
    max_heap_size: [
      type: :pos_integer_or_infinity,
      default: 8_388_608,
      doc:
        "per-agent heap limit in words (the default, 8,388,608, is 64 MiB on a 64-bit " <>
          "node; its mailbox counts too); an agent that exceeds it is killed (and restarted " <>
          "from its snapshot, up to `:max_restarts`); an arriving agent whose envelope " <>
          "alone would take half of it is refused. `:infinity` leaves agents unbounded"
    ],
    max_held: [
      type: :pos_integer,
      default: 1_000,
      doc:
        "messages, calls and other events an agent keeps while it hands off (waits for its " <>
          "destination; its messages held, the rest postponed); beyond that, posts and " <>
          "requests to it return `{:error, {:overloaded, id}}`, calls are answered so, " <>
          "anything else is dropped and counted (`:dropped`). Also the messages a paused " <>
          "copy at this host stashes while its migration is in doubt (their senders are told " <>
          "to send again beyond that): the hop's one stash bound"
    ],
    max_held_bytes: [
      type: :pos_integer,
      default: 8_388_608,
      doc:
        "bytes (external size: binaries count whole) of what an agent keeps while it hands " <>
          "off; the overflow is refused as for `:max_held`"
    ],
    security: [
      type:
        {:keyword,
         [
           keys: [
             type: {:custom, &Tartarus.Security.keys?/1},
             expected: "a key pair from Tartarus.Security.Keys.generate/0",
             doc: "the host's key pair, to seal departing agents"
           ],
           trust: [
             type: {:struct, Tartarus.Security.TrustList},
             doc: "a trust list, to admit only agents whose issuer and sending host it contains"
           ]
         ]},
      default: [],
      doc: "signed agents (see `Tartarus.Security`)"
    ],
    forward_ttl: [
      type: :timeout,
      default: :infinity,
      doc:
        "ms a forwarding pointer (and the record of a committed migration it holds) is kept " <>
          "after its agent left; older ones are swept, so messages addressed through this " <>
          "host to an agent that left longer ago get `{:error, :not_found}`. The pointer is " <>
          "also what a destination in doubt asks about: keep it well above the longest " <>
          "partition you expect, or such an agent never starts"
    ],
    max_visits: [
      type: :pos_integer_or_infinity,
      default: 64,
      doc:
        "hosts an agent's `visits` remembers (the most recently visited; see " <>
          "`Tartarus.Envelope.visit/3`): what every hop copies and ships stays bounded. " <>
          "A forgotten host counts as unvisited again, and keeps its forwarding pointer " <>
          "after the agent ends until `forward_ttl` sweeps it"
    ],
    hibernate_after: [
      type: :timeout,
      default: :infinity,
      doc:
        "ms an agent may idle before it hibernates (shrinking its memory; for hosts holding " <>
          "very many idle agents; it costs throughput on busy hosts)"
    ],
    data_dir: [
      type: :string,
      doc:
        "persistence: checkpoint agents and in-doubt migrations in this directory and " <>
          "restore them when a host of the same name starts on it again"
    ],
    durable: [
      type: :boolean,
      default: false,
      doc:
        "durable acknowledged messages: an agent acknowledges a post or request (the " <>
          "sender's `:ok`) only once it has handled it and checkpointed the new state " <>
          "(journaled under `:data_dir`, so SIGKILL and restart keep every acknowledged " <>
          "change; without `:data_dir` only the in-memory snapshot an agent restarts from " <>
          "after a crash). Off: a message is acknowledged when taken, and a restart " <>
          "restores the state of the agent's last arrival or `Tartarus.Agent.checkpoint/0`"
    ]
  ]

  @create [
    name: [type: :any, doc: "a name for the agent (defaults to module and id)"],
    static: [type: :boolean, default: false, doc: "a static agent never leaves its host"],
    owner: [type: :any, doc: "a pid that receives `{:tartarus_result, id, result}`"],
    ttl: [type: :pos_integer_or_infinity, default: :infinity, doc: "maximum number of hops"],
    seed: [type: :any, doc: "seed of the agent's random choices (defaults to its id)"],
    payload: [type: :map, default: %{}, doc: "initial data payload"],
    modules: [type: {:list, :atom}, default: [], doc: "extra modules to carry in the payload"],
    issuer: [
      type: :any,
      doc: "a key pair (`Tartarus.Security.Keys.generate/0`) to sign the agent with"
    ]
  ]

  @link [
    latency_ms: [
      type: :non_neg_integer,
      default: 0,
      doc: "one-way delay of a message over the link (a hand-off pays three)"
    ],
    loss: [type: :probability, default: 0, doc: "probability a hand-off fails"]
  ]

  @doc "The schema of `Tartarus.start_host/2`'s options."
  @spec host_schema() :: Options.schema()
  def host_schema, do: @host

  @doc "The schema of `Tartarus.create_agent/4`'s options."
  @spec create_agent_schema() :: Options.schema()
  def create_agent_schema, do: @create

  @doc "The schema of `Tartarus.connect/3`'s link properties."
  @spec link_schema() :: Options.schema()
  def link_schema, do: @link

  @doc """
  Validates `Tartarus.start_host/2`'s options. On success the options have their defaults,
  `:admission` holds a `Tartarus.Security.Admission` state and `:security` a map of the
  security settings given.
  """
  @spec host(keyword()) :: {:ok, keyword()} | {:error, String.t()}
  def host(opts) do
    where = "Tartarus.start_host/2"

    with {:ok, opts} <- Options.validate(opts, @host, where),
         {:ok, admission} <- Admission.new(opts[:admission], where) do
      {:ok,
       opts
       |> Keyword.put(:admission, admission)
       |> Keyword.put(:security, Map.new(opts[:security]))}
    end
  end

  @doc """
  Validates `Tartarus.create_agent/4`'s options. The options of a plain
  `create_mobile_agent/4` or `create_static_agent/4` (nothing but `:static`) take a fast path
  with the same result.

      iex> Tartarus.Options.Platform.create_agent(static: true) ==
      ...>   Tartarus.Options.validate([static: true], Tartarus.Options.Platform.create_agent_schema(), "x")
      true
  """
  @spec create_agent(keyword()) :: {:ok, keyword()} | {:error, String.t()}
  def create_agent(static: static) when is_boolean(static),
    do: {:ok, [static: static, ttl: :infinity, payload: %{}, modules: []]}

  def create_agent(opts), do: Options.validate(opts, @create, "Tartarus.create_agent/4")

  @doc "Validates `Tartarus.connect/3`'s link properties."
  @spec link(keyword()) :: {:ok, keyword()} | {:error, String.t()}
  def link(props), do: Options.validate(props, @link, "Tartarus.connect/3")
end
