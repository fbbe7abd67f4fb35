defmodule Tartarus.Security do
  @moduledoc """
  Signed agents: Tartarus's lock-and-key, done with public keys so that nothing secret
  travels with an agent.

  Two signatures protect an agent in transit (Ed25519, `Tartarus.Security.Signer`):

    * the **issuer's**, made once when the agent is created (`Tartarus.create_agent/4` with
      `issuer: keys`): over the agent's identity (id, module, shipped modules) and the md5 of
      every module it carries. Tampered code changes an md5 (the destination checks each
      shipped binary against its md5), so it no longer matches what the issuer signed;
    * the sending **host's**, made at every hop (host option `security: [keys: keys, ...]`):
      over the whole envelope (state, payload, hop count ...), the module list, and every
      other field of the `prepare` a receiver acts on: the migration id, its kind, the
      source host and both reply-to pids (`Tartarus.Migration.Messages.seal_fields/1`).
      Tampered state or a redirected reply no longer matches. A replayed `prepare` still
      matches its seal; what makes a replay harmless is the protocol's decision rule
      (`Tartarus.Migration.Protocol`).

  A host with `security: [trust: trust_list]` admits an agent only if both signatures are
  valid and both signers are in its trust list (`Tartarus.Security.TrustList`); otherwise the
  move is refused with `{:untrusted, reason}` (`:bad_signature`, `{:unknown_issuer, fp}`,
  `{:missing_field, field}`), the agent stays at its source, and the host emits `:refused`.

  A signed agent carries only the modules it was created with: adding a module later
  (`Tartarus.Agent.add_module/1`) breaks the issuer's signature.

  What signing does not do: the BEAM cannot sandbox code. A trusted issuer's module runs
  with every right of the node. Signatures decide *whose* code runs, not what it may do.
  """

  alias Tartarus.Security.{Signer, TrustList}

  @typedoc "Security options of a host."
  @type host_opts :: [keys: Tartarus.Security.Keys.t(), trust: TrustList.t()]

  @doc "Signs a new envelope as its issuer (called by `Tartarus.create_agent/4`)."
  @spec issue(Tartarus.Envelope.t(), Tartarus.CodeCache.manifest(), Tartarus.Security.Keys.t()) ::
          Tartarus.Envelope.t()
  def issue(env, manifest, keys) do
    sig = Signer.sign(identity(env, manifest), keys)
    %{env | issuer: keys.public, signature: %{issuer: sig}}
  end

  @doc """
  Seals a `prepare` message (`Tartarus.Migration.Messages.prepare/8`) for one hop with the
  sending host's keys: the seal, put in the envelope, covers the envelope, the manifest and
  `Tartarus.Migration.Messages.seal_fields/1`.
  """
  @spec seal_prepare(tuple(), Tartarus.Security.Keys.t()) :: tuple()
  def seal_prepare(prepare, keys) do
    {:prepare, p} = Tartarus.Migration.Messages.classify(prepare)
    env = p.env
    sigs = if is_map(env.signature), do: Map.delete(env.signature, :hop), else: %{}
    body = %{env | signature: sigs}
    hop = {keys.public, Signer.sign(sealed(p, body), keys)}
    put_elem(prepare, 6, %{env | signature: Map.put(sigs, :hop, hop)})
  end

  @doc """
  Checks an arriving `prepare` (its fields as `Tartarus.Migration.Messages.classify/1`
  gives them) against a trust list: the issuer's signature over identity and code, and the
  sending host's seal over everything a receiver acts on.
  """
  @spec check_prepare(map(), TrustList.t()) :: :ok | {:error, {:untrusted, term()}}
  def check_prepare(%{env: env, manifest: manifest} = p, trust) do
    with {:ok, sigs} <- signatures(env),
         {:ok, issuer_sig} <- fetch(sigs, :issuer),
         {:ok, {host_key, hop_sig}} <- fetch(sigs, :hop),
         :ok <- TrustList.check(trust, env.issuer, identity(env, manifest), issuer_sig),
         :ok <-
           TrustList.check(
             trust,
             host_key,
             sealed(p, %{env | signature: Map.delete(sigs, :hop)}),
             hop_sig
           ) do
      :ok
    else
      {:error, reason} -> {:error, {:untrusted, reason}}
      # A seal of the wrong shape (anything can arrive over the wire).
      _malformed -> {:error, {:untrusted, :bad_signature}}
    end
  end

  defp sealed(p, body),
    do: {Tartarus.Migration.Messages.seal_fields(p), Enum.sort(p.manifest), body}

  defp signatures(%{issuer: issuer, signature: %{} = sigs}) when is_binary(issuer),
    do: {:ok, sigs}

  defp signatures(%{issuer: nil}), do: {:error, {:missing_field, :issuer}}
  defp signatures(_), do: {:error, {:missing_field, :signature}}

  defp fetch(sigs, key) do
    case Map.fetch(sigs, key) do
      {:ok, v} -> {:ok, v}
      :error -> {:error, {:missing_field, key}}
    end
  end

  defp identity(env, manifest), do: {env.id, env.module, env.ships, Enum.sort(manifest)}

  @doc false
  # Validates the `:security` host option.
  def validate_host_opts(opts) do
    cond do
      not Keyword.keyword?(opts) ->
        {:error, "expected a keyword list with :keys and/or :trust, got: #{inspect(opts)}"}

      (keys = opts[:keys]) != nil and not keys?(keys) ->
        {:error,
         "expected :keys to be a key pair from Tartarus.Security.Keys.generate/0, got: #{inspect(keys)}"}

      (trust = opts[:trust]) != nil and not is_struct(trust, TrustList) ->
        {:error, "expected :trust to be a Tartarus.Security.TrustList, got: #{inspect(trust)}"}

      true ->
        {:ok, Map.new(opts)}
    end
  end

  @doc false
  def keys?(%{public: <<_::256>>, secret: <<_::256>>}), do: true
  def keys?(_), do: false
end
