defmodule Tartarus.Host do
  @moduledoc """
  Hosts: where agents live and what they migrate between (DESIGN §4).

  A host is addressed by `{name, node}`; on its own node a bare `name` is enough. Names are
  atoms or strings. A host has:

    * an **overlay neighbour set**, with optional per-link properties (`:latency_ms`,
      `:loss`) that emulations use; agents usually move to neighbours;
    * a **ledger**: resident agents, arrival and departure counts, recent hop times, visit
      count, forwarding pointers for departed agents, and migration decisions;
    * a **store**: a small key-value table that agents on the host read and write
      (`Tartarus.Agent.store_get/2`, `store_put/2`);
    * **plugins**: device drivers reachable by the agents on the host (`Tartarus.Plugin`).

  Users go through the `Tartarus` facade; this module holds the host options and the few
  helpers the other platform modules share.
  """

  alias Tartarus.Options

  @typedoc "A host's name: an atom or a string."
  @type name :: atom() | String.t()

  @typedoc "A host's address."
  @type t :: {name(), node()}

  @schema [
    neighbours: [
      type: {:list, :host},
      default: [],
      doc: "hosts to link to at start (links are symmetric; remote hosts must be running)"
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
      type: :keyword,
      doc:
        "an admission policy for arriving agents (see `Tartarus.Security.Admission`: " <>
          "`:max_resident_agents`, `:max_envelope_bytes`, `:max_payload_bytes`, `:max_hops`, `:rate`)"
    ],
    max_envelope_bytes: [
      type: :pos_integer,
      default: Tartarus.Wire.default_max_bytes(),
      doc: "largest hand-off message (envelope and code) the host accepts"
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
      default: :infinity,
      doc: "per-agent heap limit in words; an agent that exceeds it is killed (and restarted)"
    ],
    security: [
      type: :keyword,
      doc:
        "signed agents (see `Tartarus.Security`): `keys:` the host's key pair, to seal " <>
          "departing agents; `trust:` a trust list, to admit only agents whose issuer and " <>
          "sending host it contains"
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
    ]
  ]

  @doc false
  def schema, do: @schema

  @doc false
  @spec validate_opts(keyword()) :: {:ok, keyword()} | {:error, String.t()}
  def validate_opts(opts) do
    with {:ok, opts} <- Options.validate(opts, @schema, "Tartarus.start_host/2"),
         {:ok, opts} <- validate_security(opts) do
      case opts[:admission] do
        nil ->
          {:ok, opts}

        policy ->
          case Tartarus.Security.Admission.new(policy) do
            {:ok, admission} ->
              {:ok, Keyword.put(opts, :admission, admission)}

            {:error, message} ->
              {:error,
               "invalid options given to Tartarus.start_host/2 for key :admission: " <> message}
          end
      end
    end
  end

  defp validate_security(opts) do
    case Tartarus.Security.validate_host_opts(opts[:security] || []) do
      {:ok, security} ->
        {:ok, Keyword.put(opts, :security, security)}

      {:error, message} ->
        {:error, "invalid options given to Tartarus.start_host/2 for key :security: " <> message}
    end
  end

  @doc """
  True if `term` is a host name or address.

      iex> Tartarus.Host.address?(:a)
      true
      iex> Tartarus.Host.address?({"lab-3", :"n1@pi"})
      true
      iex> Tartarus.Host.address?(3)
      false
  """
  @spec address?(term()) :: boolean()
  def address?({name, node}), do: name?(name) and is_atom(node) and node != nil
  def address?(name), do: name?(name)

  defp name?(name) when is_boolean(name) or is_nil(name), do: false
  defp name?(name), do: is_atom(name) or (is_binary(name) and byte_size(name) in 1..255)

  @doc """
  The full address of a host: a bare name means a host on this node.

      iex> Tartarus.Host.address(:a)
      {:a, node()}
  """
  @spec address(name() | t()) :: t()
  def address({_name, _node} = host), do: host
  def address(name), do: {name, node()}

  @doc false
  # The pid of a host's server, local or remote.
  @spec whereis(name() | t()) :: {:ok, pid()} | {:error, {:unknown_host, term()}}
  def whereis(host) do
    if address?(host),
      do: Tartarus.Host.Directory.whereis(address(host)),
      else: {:error, {:unknown_host, host}}
  end

  @doc false
  # The tables and settings of a host on this node, read without calling its server.
  @spec local(name() | t()) :: {:ok, map()} | {:error, {:unknown_host, term()}}
  def local(host) do
    {name, node} = if address?(host), do: address(host), else: {host, nil}

    # The registry forgets a stopped host asynchronously: check that it is alive.
    with true <- node == node(),
         [{pid, %{} = info}] <- Registry.lookup(Tartarus.HostRegistry, {:host, name}),
         true <- Process.alive?(pid) do
      {:ok, info}
    else
      _ -> {:error, {:unknown_host, host}}
    end
  end

  @doc false
  # Calls a host's server, turning a dead host or node into an error.
  @spec call(name() | t(), term(), timeout()) :: term()
  def call(host, request, timeout \\ 5_000) do
    with {:ok, pid} <- whereis(host) do
      try do
        GenServer.call(pid, request, timeout)
      catch
        :exit, {:timeout, _} ->
          {:error, {:timeout, address(host)}}

        :exit, _ ->
          Tartarus.Host.Directory.forget(address(host))
          {:error, {:unknown_host, address(host)}}
      end
    end
  end
end
