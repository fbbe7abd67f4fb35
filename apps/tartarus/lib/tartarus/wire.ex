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

  alias Tartarus.Envelope
  alias Tartarus.Migration.Messages

  @max_name_bytes 256
  @max_modules 64
  @envelope_size map_size(%Envelope{id: nil, module: nil})
  @default_max_bytes 8 * 1024 * 1024

  @doc "The default upper bound of a hand-off message's size, in bytes (8 MiB)."
  @spec default_max_bytes() :: pos_integer()
  def default_max_bytes, do: @default_max_bytes

  @doc """
  Checks a prepare message's fields (not the seal: `Tartarus.Security.check_prepare/2`).

      iex> Tartarus.Wire.check_prepare(:nonsense, 1_000)
      {:error, {:bad_message, :not_a_prepare}}
  """
  @spec check_prepare(term(), pos_integer()) :: :ok | {:error, {:bad_message, term()}}
  def check_prepare(
        {:"$tartarus_prepare", s_pid, mig, src, src_pid, kind, env, manifest, code},
        max_bytes
      ) do
    with :ok <- check(is_pid(s_pid) and is_pid(src_pid), :pids),
         :ok <- check(Messages.migration_id?(mig), :migration_id),
         :ok <- check(address?(src) and is_tuple(src), :source_host),
         :ok <- check(kind in [:move, :clone], :kind),
         :ok <- check_envelope(env),
         :ok <- check_manifest(manifest),
         :ok <- check_code(code) do
      size = :erlang.external_size({env, manifest, code})
      check(size <= max_bytes, {:too_large, size, max_bytes})
    end
  end

  def check_prepare(_other, _max), do: {:error, {:bad_message, :not_a_prepare}}

  @doc """
  Checks an envelope: a `Tartarus.Envelope` with every field of the right type.

      iex> Tartarus.Wire.check_envelope(%{__struct__: Tartarus.Envelope, id: 1})
      {:error, {:bad_message, {:envelope, :fields}}}
  """
  @spec check_envelope(term()) :: :ok | {:error, {:bad_message, term()}}
  def check_envelope(
        %{
          __struct__: Envelope,
          id: id,
          name: name,
          module: module,
          ships: ships,
          payload: payload,
          owner: owner,
          home: home,
          hops: hops,
          ttl: ttl,
          visits: visits,
          visit_order: order,
          from: from,
          departed_at: departed_at,
          static: static,
          rng: rng,
          clone_of: clone_of,
          issuer: issuer,
          signature: signature
        } = env
      )
      when map_size(env) == @envelope_size do
    # One pass of plain checks: this runs for every arriving agent.
    cond do
      not (is_binary(id) and byte_size(id) == 16) ->
        bad(:id)

      not (is_nil(name) or is_atom(name) or
               (is_binary(name) and byte_size(name) <= @max_name_bytes)) ->
        bad(:name)

      not (is_atom(module) and module != nil) ->
        bad(:module)

      not module_list?(ships) ->
        bad(:ships)

      not payload?(payload) ->
        bad(:payload)

      not (is_nil(owner) or is_pid(owner)) ->
        bad(:owner)

      not (is_nil(home) or address?(home)) ->
        bad(:home)

      not (is_integer(hops) and hops >= 0) ->
        bad(:hops)

      not (ttl == :infinity or (is_integer(ttl) and ttl > 0)) ->
        bad(:ttl)

      not visited?(visits, order) ->
        if is_map(visits) and visits?(visits), do: bad(:visit_order), else: bad(:visits)

      not (is_nil(from) or address?(from)) ->
        bad(:from)

      not (is_nil(departed_at) or is_integer(departed_at)) ->
        bad(:departed_at)

      not is_boolean(static) ->
        bad(:static)

      not rng?(rng) ->
        bad(:rng)

      not (is_nil(clone_of) or (is_binary(clone_of) and byte_size(clone_of) == 16)) ->
        bad(:clone_of)

      not (is_nil(issuer) or is_binary(issuer)) ->
        bad(:issuer)

      not (is_nil(signature) or is_binary(signature) or is_map(signature)) ->
        bad(:signature)

      true ->
        :ok
    end
  end

  def check_envelope(%{__struct__: Envelope}), do: {:error, {:bad_message, {:envelope, :fields}}}
  def check_envelope(_other), do: {:error, {:bad_message, {:envelope, :not_an_envelope}}}

  defp bad(field), do: {:error, {:bad_message, {:envelope, field}}}

  defp module_list?(l),
    do: is_list(l) and length(l) <= @max_modules and Enum.all?(l, &(is_atom(&1) and &1 != nil))

  defp payload?(%{data: data, modules: mods} = p) when map_size(p) == 2,
    do: is_map(data) and module_list?(mods)

  defp payload?(_), do: false

  defp visits?(v) when is_map(v) do
    :maps.fold(
      fn h, n, ok -> ok and is_integer(n) and n >= 0 and address?(h) end,
      true,
      v
    )
  end

  defp visits?(_), do: false

  # `visits` and its order (most recent first) in one pass: the order is a proper list (a
  # guard's length/1 is false for any other) of every key of `visits` once, each an address
  # with a count. (Every hop checks this: it is as long as the agent's `max_visits`.)
  defp visited?(visits, order) when is_map(visits) and length(order) == map_size(visits) do
    Enum.all?(order, fn h ->
      case visits do
        %{^h => n} when is_integer(n) and n >= 0 -> address?(h)
        _ -> false
      end
    end) and map_size(:maps.from_keys(order, [])) == map_size(visits)
  end

  defp visited?(_, _), do: false

  # An exported :rand state: {algorithm, state}; :rand.seed_s/1 checks the rest when used.
  defp rng?({alg, _state})
       when alg in [:exsss, :exsplus, :exrop, :exs1024s, :exs64, :exs1024, :exsp, :exro928ss],
       do: true

  defp rng?(_), do: false

  # As Tartarus.Host.address?/1 (kept here so that the protocol depends on no other module
  # of the platform but the envelope).
  defp address?({name, node}), do: name?(name) and is_atom(node) and node != nil
  defp address?(name), do: name?(name)

  defp name?(name) when is_boolean(name) or is_nil(name), do: false
  defp name?(name), do: is_atom(name) or (is_binary(name) and byte_size(name) in 1..255)

  @doc "Checks a manifest: a list of `{module, md5}` pairs."
  @spec check_manifest(term()) :: :ok | {:error, {:bad_message, term()}}
  def check_manifest(m) when is_list(m) and length(m) <= @max_modules do
    check(
      Enum.all?(m, &match?({mod, <<_::128>>} when is_atom(mod) and mod != nil, &1)),
      :manifest
    )
  end

  def check_manifest(_), do: {:error, {:bad_message, :manifest}}

  @doc "Checks shipped code: a list of `{module, md5, beam_binary}`."
  @spec check_code(term()) :: :ok | {:error, {:bad_message, term()}}
  def check_code(c) when is_list(c) and length(c) <= @max_modules do
    ok =
      Enum.all?(
        c,
        &match?({mod, <<_::128>>, bin} when is_atom(mod) and mod != nil and is_binary(bin), &1)
      )

    check(ok, :code)
  end

  def check_code(_), do: {:error, {:bad_message, :code}}

  @doc """
  Checks a decision query.

      iex> Tartarus.Wire.check_decision_query({:"$tartarus_decision?", 1, 2, 3, 4})
      {:error, {:bad_message, :decision_query}}
  """
  @spec check_decision_query(term()) :: :ok | {:error, {:bad_message, term()}}
  def check_decision_query({:"$tartarus_decision?", mig, id, copy, pid}) do
    check(
      Messages.migration_id?(mig) and is_binary(id) and byte_size(id) <= @max_name_bytes and
        Messages.copy_token?(copy) and is_pid(pid),
      :decision_query
    )
  end

  def check_decision_query(_), do: {:error, {:bad_message, :decision_query}}

  @doc """
  Checks a batch of acknowledgements (at most 1_000).

      iex> Tartarus.Wire.check_acks({:"$tartarus_acks", [:x]})
      {:error, {:bad_message, :acks}}
  """
  @spec check_acks(term()) :: :ok | {:error, {:bad_message, term()}}
  def check_acks({:"$tartarus_acks", list}) when is_list(list) do
    check(
      length(list) <= 1_000 and
        Enum.all?(list, fn
          {mig, id, copy} ->
            Messages.migration_id?(mig) and is_binary(id) and byte_size(id) <= @max_name_bytes and
              Messages.copy_token?(copy)

          _ ->
            false
        end),
      :acks
    )
  end

  def check_acks(_), do: {:error, {:bad_message, :acks}}

  @doc "Checks a call to a host's server."
  @spec check_call(term()) :: :ok | {:error, {:bad_message, term()}}
  def check_call(:info), do: :ok
  def check_call(:monitored), do: :ok
  def check_call(:restore), do: :ok
  def check_call(:adopted), do: :ok
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
