defmodule Tartarus.Wire do
  @moduledoc """
  Checks of what a host receives from other nodes, before any of it is used.

  Every hand-off message and every request to a host's server is checked for shape, types
  and size here; a message that fails is refused with `{:bad_message, what}` (and an event)
  and never reaches code that could crash on it. These functions are pure and total: they
  return `:ok` or `{:error, reason}` for any term, which the property tests check with
  thousands of generated malformed messages.

  What this cannot do: distributed Erlang decodes a message, creating any atoms in it,
  before we see it. Nothing here turns remote data into atoms (`String.to_atom/1`,
  `binary_to_term/1` without `:safe` are not used on remote data), but a connected node can
  still send atoms; only TLS distribution with certificates (DESIGN §7) decides who may
  connect at all.
  """

  @max_name_bytes 256
  @default_max_bytes 8 * 1024 * 1024

  @doc "The default upper bound of a hand-off message's size, in bytes (8 MiB)."
  @spec default_max_bytes() :: pos_integer()
  def default_max_bytes, do: @default_max_bytes

  @doc """
  Checks a prepare message's fields (`Tartarus.Migration.Protocol.check_prepare/2`).

      iex> Tartarus.Wire.check_prepare(:nonsense, 1_000)
      {:error, {:bad_message, :not_a_prepare}}
  """
  @spec check_prepare(term(), pos_integer()) :: :ok | {:error, {:bad_message, term()}}
  defdelegate check_prepare(msg, max_bytes), to: Tartarus.Migration.Protocol

  @doc """
  Checks an envelope: a `Tartarus.Envelope` with every field of the right type
  (`Tartarus.Migration.Protocol.check_envelope/1`).

      iex> Tartarus.Wire.check_envelope(%{__struct__: Tartarus.Envelope, id: 1})
      {:error, {:bad_message, {:envelope, :fields}}}
  """
  @spec check_envelope(term()) :: :ok | {:error, {:bad_message, term()}}
  defdelegate check_envelope(env), to: Tartarus.Migration.Protocol

  @doc "Checks a manifest (`Tartarus.Migration.Protocol.check_manifest/1`)."
  @spec check_manifest(term()) :: :ok | {:error, {:bad_message, term()}}
  defdelegate check_manifest(m), to: Tartarus.Migration.Protocol

  @doc "Checks shipped code (`Tartarus.Migration.Protocol.check_code/1`)."
  @spec check_code(term()) :: :ok | {:error, {:bad_message, term()}}
  defdelegate check_code(c), to: Tartarus.Migration.Protocol

  @doc "Checks a decision query (`Tartarus.Migration.Protocol.check_decision_query/1`)."
  @spec check_decision_query(term()) :: :ok | {:error, {:bad_message, term()}}
  defdelegate check_decision_query(q), to: Tartarus.Migration.Protocol

  @doc "Checks a call to a host's server."
  @spec check_call(term()) :: :ok | {:error, {:bad_message, term()}}
  def check_call(:info), do: :ok
  def check_call(:monitored), do: :ok
  def check_call(:restore), do: :ok
  def check_call(:paused), do: :ok
  def check_call(:parked), do: :ok
  def check_call({:create, env, _args}), do: check_envelope(env)

  def check_call({:connect, host, props}),
    do: check(Tartarus.Host.address?(host) and is_tuple(host) and link_props?(props), :connect)

  def check_call({:disconnect, host}), do: check(Tartarus.Host.address?(host), :disconnect)
  def check_call({:locate, agent}), do: check(agent_key?(agent), :locate)
  def check_call({:kill, agent}), do: check(agent_key?(agent), :kill)
  def check_call({:park, _mig, _copy, _env, _src, _kind}), do: :ok
  def check_call(_), do: {:error, {:bad_message, :unknown_call}}

  defp link_props?(%{latency_ms: l, loss: p} = m) when map_size(m) == 2,
    do: is_integer(l) and l >= 0 and is_number(p) and p >= 0 and p <= 1

  defp link_props?(_), do: false

  defp agent_key?(a), do: (is_binary(a) and byte_size(a) <= @max_name_bytes) or is_atom(a)

  defp check(true, _what), do: :ok
  defp check(false, what), do: {:error, {:bad_message, what}}
end
