defmodule Tartarus.Security.Signer do
  @moduledoc """
  Signs and verifies terms, agent envelopes and shipped modules with Ed25519 issuer keys.

      keys = Tartarus.Security.Keys.generate()
      trust = Tartarus.Security.TrustList.new([keys.public])

      envelope = Tartarus.Security.Signer.sign_envelope(%{agent: MyAgent, state: %{n: 1}}, keys)
      :ok = Tartarus.Security.Signer.verify_envelope(envelope, trust)

      sig = Tartarus.Security.Signer.sign_module(MyAgent, beam, keys)
      :ok = Tartarus.Security.Signer.verify_module(MyAgent, beam, sig, trust)

  ## What is signed

  A signature covers a *canonical* encoding of the term:
  `:erlang.term_to_binary(term, [:deterministic, minor_version: 2])`. `:deterministic`
  (OTP 24.1+) fixes the order of map keys, and `minor_version: 2` fixes how atoms and floats
  are written, so the same term gives the same bytes on every node and OTP release. Each kind
  of signed thing carries its own context tag inside the signed bytes, so a signature over an
  envelope can never be replayed as a signature over a module or a bare term.

  Pids, references, ports and funs encode the node they belong to; they are signed like any
  other term, but a copy made on another node will not verify. Envelopes should hold plain data.

  ## Envelopes

  `sign_envelope/2` signs every field of a map except `:signature`, after putting the issuer's
  public key in `:issuer`; so the issuer is covered by the signature. Any change to any other
  field, to the issuer or to the signature makes `verify_envelope/2` fail. Structs work when
  they have `:issuer` and `:signature` fields.

  ## Modules

  `sign_module/3` signs the module name with the MD5 (the code cache key) and the SHA-256 of
  the exact BEAM binary, so the signature is checked against the bytes that will be loaded.
  `verify_module/4` recomputes both from the binary it received and checks that the binary
  really defines the named module.

  ## Errors

    * `{:error, :bad_signature}` - the bytes were changed, or signed by another key;
    * `{:error, {:unknown_issuer, fingerprint}}` - the signer is not in the trust list;
    * `{:error, {:missing_field, :issuer | :signature}}` - an unsigned envelope;
    * `{:error, {:module_mismatch, expected, got}}` - the binary defines another module;
    * `{:error, {:invalid_beam, module}}` - the binary is not a BEAM file;
    * `{:error, {:invalid_envelope | :invalid_module_signature, message}}` - input of the wrong
      shape (these functions take wire input: they answer errors, they do not raise).
  """

  alias Tartarus.Security.{Keys, TrustList}

  @typedoc "An Ed25519 signature: 64 raw bytes."
  @type signature :: <<_::512>>

  @typedoc "A map signed by `sign_envelope/2`."
  @type envelope :: %{
          required(:issuer) => Keys.public_key(),
          required(:signature) => signature(),
          optional(any) => any
        }

  @typedoc "The signature of one shipped module, from `sign_module/3`."
  @type module_signature :: %{
          module: module(),
          md5: binary(),
          issuer: Keys.public_key(),
          signature: signature()
        }

  @typedoc "Why a verification failed."
  @type verify_error ::
          :bad_signature
          | {:unknown_issuer, String.t()}
          | {:missing_field, :issuer | :signature}
          | {:module_mismatch, expected :: module(), got :: module()}
          | {:invalid_beam, module()}
          | {:invalid_envelope, String.t()}
          | {:invalid_module_signature, String.t()}

  @term_tag "tartarus/term/v1"
  @envelope_tag "tartarus/envelope/v1"
  @module_tag "tartarus/module/v1"

  @doc """
  The canonical bytes of `term`, the ones a signature covers.

  ## Examples

      iex> a = Tartarus.Security.Signer.canonical(%{b: 1, a: 2})
      iex> a == Tartarus.Security.Signer.canonical(Map.new([{:a, 2}, {:b, 1}]))
      true
  """
  @spec canonical(term()) :: binary()
  defdelegate canonical(term), to: Keys

  @doc """
  Signs `term` with the secret key of `keys`.

  ## Examples

      iex> keys = Tartarus.Security.Keys.generate()
      iex> sig = Tartarus.Security.Signer.sign({:hello, 1}, keys)
      iex> Tartarus.Security.Signer.verify({:hello, 1}, sig, keys.public)
      :ok
      iex> Tartarus.Security.Signer.verify({:hello, 2}, sig, keys.public)
      {:error, :bad_signature}
  """
  @spec sign(term(), Keys.t()) :: signature()
  def sign(term, keys), do: sign_tagged(@term_tag, term, keys)

  @doc """
  Checks that `signature` was made over `term` by the owner of `public_key`.

  Returns `{:error, :bad_signature}` for any mismatch, including a malformed signature or key.
  """
  @spec verify(term(), binary(), Keys.public_key()) :: :ok | {:error, :bad_signature}
  defdelegate verify(term, signature, public_key), to: Keys

  @doc """
  Signs a map: puts the issuer's public key in `:issuer`, signs every field except
  `:signature`, and stores the signature in `:signature`. Any earlier signature is replaced.

  ## Examples

      iex> keys = Tartarus.Security.Keys.generate()
      iex> env = Tartarus.Security.Signer.sign_envelope(%{state: %{n: 1}}, keys)
      iex> env.issuer == keys.public and byte_size(env.signature) == 64
      true
  """
  @spec sign_envelope(map(), Keys.t()) :: envelope()
  def sign_envelope(map, %{public: public} = keys) when is_map(map) do
    body = map |> Map.delete(:signature) |> Map.put(:issuer, public)
    Map.put(body, :signature, sign_tagged(@envelope_tag, body, keys))
  end

  def sign_envelope(other, _keys) do
    raise ArgumentError, "expected a map to sign as an envelope, got: #{inspect(other)}"
  end

  @doc """
  Verifies an envelope made by `sign_envelope/2` against a trust list.

  ## Examples

      iex> keys = Tartarus.Security.Keys.generate()
      iex> trust = Tartarus.Security.TrustList.new([keys.public])
      iex> env = Tartarus.Security.Signer.sign_envelope(%{state: 1}, keys)
      iex> Tartarus.Security.Signer.verify_envelope(env, trust)
      :ok
      iex> Tartarus.Security.Signer.verify_envelope(%{env | state: 2}, trust)
      {:error, :bad_signature}
  """
  @spec verify_envelope(map(), TrustList.t()) :: :ok | {:error, verify_error()}
  def verify_envelope(%{issuer: issuer, signature: signature} = envelope, %TrustList{} = trust) do
    with :ok <- TrustList.check_issuer(trust, issuer) do
      verify_tagged(@envelope_tag, Map.delete(envelope, :signature), signature, issuer)
    end
  end

  def verify_envelope(envelope, %TrustList{}) when is_map(envelope) do
    missing = if Map.has_key?(envelope, :issuer), do: :signature, else: :issuer
    {:error, {:missing_field, missing}}
  end

  def verify_envelope(other, %TrustList{}) do
    {:error,
     {:invalid_envelope, "expected a map with :issuer and :signature, got: #{inspect(other)}"}}
  end

  @doc """
  Signs a module's BEAM binary: its name, MD5 and SHA-256.

  The result travels beside the binary; it holds no secret.
  """
  @spec sign_module(module(), binary(), Keys.t()) :: module_signature()
  def sign_module(module, beam, %{public: public} = keys)
      when is_atom(module) and is_binary(beam) do
    md5 = :erlang.md5(beam)

    %{
      module: module,
      md5: md5,
      issuer: public,
      signature: sign_tagged(@module_tag, module_digest(module, beam, md5), keys)
    }
  end

  @doc """
  Verifies a module binary against its `t:module_signature/0` and a trust list.

  Checks, in order: the issuer is trusted, the binary is a BEAM file defining `module`, and the
  signature covers this module name and these exact bytes.
  """
  @spec verify_module(module(), binary(), module_signature(), TrustList.t()) ::
          :ok | {:error, verify_error()}
  def verify_module(
        module,
        beam,
        %{issuer: issuer, signature: signature},
        %TrustList{} = trust
      )
      when is_atom(module) and is_binary(beam) do
    with :ok <- TrustList.check_issuer(trust, issuer),
         :ok <- check_beam_module(module, beam) do
      digest = module_digest(module, beam, :erlang.md5(beam))
      verify_tagged(@module_tag, digest, signature, issuer)
    end
  end

  def verify_module(module, beam, sig, %TrustList{})
      when is_atom(module) and is_binary(beam) and is_map(sig) do
    missing = if Map.has_key?(sig, :issuer), do: :signature, else: :issuer
    {:error, {:missing_field, missing}}
  end

  def verify_module(module, beam, sig, %TrustList{}) do
    {:error,
     {:invalid_module_signature,
      "expected a module name, a BEAM binary and a map with :issuer and :signature, got: " <>
        "#{inspect(module)}, #{if is_binary(beam), do: "a binary", else: inspect(beam)}, " <>
        inspect(sig)}}
  end

  defp module_digest(module, beam, md5), do: {module, md5, :crypto.hash(:sha256, beam)}

  defp check_beam_module(module, beam) do
    case :beam_lib.info(beam) do
      info when is_list(info) ->
        case Keyword.fetch!(info, :module) do
          ^module -> :ok
          other -> {:error, {:module_mismatch, module, other}}
        end

      {:error, :beam_lib, _} ->
        {:error, {:invalid_beam, module}}
    end
  end

  defp sign_tagged(tag, term, %{secret: secret}) do
    :crypto.sign(:eddsa, :none, tag <> canonical(term), [secret, :ed25519])
  end

  defp verify_tagged(tag, term, signature, public)
       when byte_size(signature) == 64 and byte_size(public) == 32 do
    if :crypto.verify(:eddsa, :none, tag <> canonical(term), signature, [public, :ed25519]),
      do: :ok,
      else: {:error, :bad_signature}
  end

  defp verify_tagged(_tag, _term, _signature, _public), do: {:error, :bad_signature}
end
